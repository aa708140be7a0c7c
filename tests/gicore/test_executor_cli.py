"""The executor's command-line options: a bad Ray address, --ray-address without --executor ray and Ray not
installed are each one error line (the scripts' ``main`` in this process, Ray made unimportable where it
should be missing), and without Ray the local paths import and render (a real process)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.cli import check_user_error, run_main
from tests.helpers.cloud import write_scenes
from tests.helpers.guards import HANG_GUARD_S

DATASET = ["gicore-dataset", "ball_moving.json", "--out", "out", "--train", "1", "--val", "0"]
DATASET += ["--resolution", "8", "--spp", "1", "--no-denoise"]
PREBAKE = ["cloudbaking-prebake", "ball_moving.json", "--store", "store", "--frames", "2"]
PREBAKE += ["--resolution", "16", "--spp", "1"]
NOT_INSTALLED = "needs Ray, which is not installed: install it with pip install '.[ray]'"


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("cli_scenes"))


@pytest.mark.parametrize("argv", [DATASET, PREBAKE], ids=["dataset", "prebake"])
@pytest.mark.parametrize(
    ("address", "culprit"),
    [
        ("127.0.0.1:1", "--ray-address 127.0.0.1:1: no Ray cluster answers there (Connection refused)"),
        ("headnode", "--ray-address 'headnode' is neither 'auto' nor HOST:PORT"),
        ("10.0.0.5:99999", "--ray-address '10.0.0.5:99999' is neither 'auto' nor HOST:PORT"),
    ],
)
def test_a_bad_ray_address_is_one_error_line(
    argv: list[str],
    address: str,
    culprit: str,
    scenes: Path,
    monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
) -> None:
    import ray

    # A process already connected to Ray keeps its connection whatever the address: none is here.
    assert not ray.is_initialized()
    # the culprit is the address check's, made before Ray is asked (which would reconnect for minutes)
    outcome = run_main([*argv, "--executor", "ray", "--ray-address", address], scenes, monkeypatch, capfd)
    assert outcome.returncode == 2 and "Traceback" not in outcome.stdout + outcome.stderr, outcome.stderr
    errors = [line for line in outcome.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and culprit in errors[0], outcome.stderr
    # nothing rendered or stored, and no folder left behind
    assert not (scenes / "out").exists() and not (scenes / "store").exists()


@pytest.mark.parametrize("argv", [DATASET, PREBAKE], ids=["dataset", "prebake"])
def test_a_ray_address_without_executor_ray_is_one_error_line(
    argv: list[str], scenes: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    culprit = "--ray-address needs --executor ray: add --executor ray, or leave out --ray-address"
    check_user_error(run_main([*argv, "--ray-address", "auto"], scenes, monkeypatch, capfd), culprit)


@pytest.mark.parametrize(
    ("argv", "culprit"),
    [
        ([*DATASET, "--executor", "ray"], f"--executor ray {NOT_INSTALLED}"),
        ([*PREBAKE, "--executor", "ray"], f"--executor ray {NOT_INSTALLED}"),
        (["bench", "scaling", "--quick", "--out", "out"], f"--executors ray {NOT_INSTALLED}"),
    ],
    ids=["dataset", "prebake", "bench-scaling"],
)
def test_ray_not_installed_names_the_extra(
    argv: list[str], culprit: str, scenes: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails, as on an install without the extra
    check_user_error(run_main(argv, scenes, monkeypatch, capfd), culprit)


#: A fresh interpreter imports every module with an executor option, then renders a data set with Ray made
#: unimportable, as on an install without the extra.
WITHOUT_RAY = (
    "import sys; import gicore, gicore.executor, gicore.dataset_cli, baseline_cloudbaking.prebake_cli, bench.cli; "
    "assert 'ray' not in sys.modules, 'ray imported'; sys.modules['ray'] = None; "
    "from gicore.dataset_cli import main; main()"
)


def test_without_ray_the_local_paths_import_and_render(scenes: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-c", WITHOUT_RAY, *DATASET[1:3], str(out), *DATASET[4:]],
        cwd=scenes,
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert proc.returncode == 0, proc.stderr
    assert [p.name for p in out.rglob("*.npz")] == ["000000.npz"]
