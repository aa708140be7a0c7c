"""The Web3D viewer (docs/architecture.md, Web3D viewer): GIGAN and cloud baking side by side in a browser.

- :mod:`web3d.export`: the scene's meshes, materials, WebGL2 shaders (``gicore.gl``'s GLSL, ported by its
  version line and precision qualifiers) and camera path as static files, plus the shipped ONNX model;
- :mod:`web3d.serve`: ``gigan-web``'s server (Starlette on uvicorn): the page, its npm files and the assets,
  ``POST /v1/gimap`` forwarded to the chosen profile's ``network-sim`` proxy of the chosen store's cloud-baking
  server (:mod:`web3d.children` starts them), the shadow-map setups; one origin, so no CORS;
- the page itself lives in ``web3d/static/`` (ES modules, onnxruntime-web from ``web/node_modules``).

This package sits beside ``bench``: it depends on ``gicore`` and on ``gigan_local``'s model files, and
passes cloud-baking payloads through as bytes (the browser decodes them).
"""


def main() -> None:
    """``gigan-web``: :mod:`web3d.cli`, a service, loaded as :func:`gicore.error_policy.launch` loads one (a stop
    while its modules load, a second or two, ends it quietly)."""
    from gicore.error_policy import launch

    launch("web3d.cli", services=True)
