"""The cloud-baking GI-map server: a FastAPI app (:func:`~baseline_cloudbaking.server.app.create_app`) run
by uvicorn as its own process (``cloudbaking-server``)."""


def main() -> None:
    """``cloudbaking-server``: :mod:`baseline_cloudbaking.server.cli`, a service, loaded as
    :func:`gicore.error_policy.launch` loads one (a stop while its modules load ends it quietly)."""
    from gicore.error_policy import launch

    launch("baseline_cloudbaking.server.cli", services=True)
