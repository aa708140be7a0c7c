"""The cloud-baking GI-map server: a FastAPI app (:func:`~baseline_cloudbaking.server.app.create_app`) run
by uvicorn as its own process (``cloudbaking-server``)."""
