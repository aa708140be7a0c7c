"""Every console script fails cleanly on bad input (docs/architecture.md, Errors).

Each row runs one installed console script as a subprocess, in its own copy of a scratch workspace that
holds valid and broken inputs (see :func:`workspace`), and checks the policy: exit status 2, exactly one
``error:`` line on stderr that names the culprit (the file or field at fault), no traceback, and nothing
written, changed or left behind in the workspace.

To cover a new script, add rows to ``CASES`` with :func:`case` (argv relative to the workspace; put new
inputs in :func:`workspace`), or call :func:`assert_user_error` from your own test module. The rows run
a few at a time (``outcomes``): each costs one interpreter start with its imports (~1-2 s of CPU).
"""

from __future__ import annotations

import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import pytest

from tests.helpers.cli import BIN, TIMEOUT_S, Outcome, check_user_error, run_script


def case(*argv: str, culprit: str, id: str, hold: str | None = None):
    """A row of ``CASES``: ``hold`` names a workspace folder that another run holds meanwhile."""
    return pytest.param(list(argv), culprit, hold, id=id)


# -- the workspace -------------------------------------------------------------------------------------------------
SPEC = (
    'name = "{name}"\n[[objects]]\nname = "organ"\nmesh = {mesh}\n'
    "[light]\nposition = [0, 2, 0]\nintensity = {intensity}\n{extra}"
)


def write_spec(
    path: Path, name: str = "s", mesh: str = '"meshes/ball.obj"', intensity: float = 3.0, extra: str = ""
) -> None:
    path.write_text(SPEC.format(name=name, mesh=mesh, intensity=intensity, extra=extra))


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory, sphere_mesh_path: Path) -> Path:
    """Valid inputs (a scene spec, a rendered dataset, a synthetic dataset, a one-step training run, the
    shipped model) and broken copies of each, all under one folder the cases run in."""
    import torch

    from gicore.dataset_cli import DatasetConfig, build_dataset
    from gicore.scene import load_scene
    from gigan_local.inference import DEFAULT_MODEL
    from gigan_local.train import train
    from tests.helpers.training import make_dataset, tiny_config

    ws = tmp_path_factory.mktemp("cli_errors")
    (ws / "afile").write_text("a file where a folder belongs\n")
    meshes = ws / "meshes"
    meshes.mkdir()
    shutil.copy(sphere_mesh_path, meshes / "ball.obj")
    (meshes / "empty.obj").write_bytes(b"")
    (meshes / "text.obj").write_text("this is not a mesh\n")
    (meshes / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 1\nf 1 2 3\nf 1 2 4\n")

    write_spec(ws / "scene.toml")
    write_spec(ws / "bad_field.toml", intensity=-3.0)
    write_spec(ws / "bad_name.toml", name="../../x")
    write_spec(ws / "empty_name.toml", name="")
    write_spec(ws / "near.toml", extra="[camera]\nnear = 1e-20\n")
    for kind in ("missing", "empty", "text", "nan"):
        write_spec(ws / f"mesh_{kind}.toml", mesh=f'"meshes/{kind}.obj"')
    write_spec(ws / "mesh_5.toml", mesh="5")
    (ws / "broken.toml").write_text('name = "s"\n[light\n')

    # A dataset rendered by gicore-dataset (tiny), and synthetic ones with a broken meta.json or frame.
    build_dataset(
        load_scene(ws / "scene.toml"),
        ws / "rendered" / "s",
        DatasetConfig(n_train=1, n_val=0, resolution=8, spp=1, denoise=False),
        progress=False,
    )
    make_dataset(ws / "ds", res=32, n_train=2, n_val=1)
    shutil.copytree(ws / "ds", ws / "ds_badmeta")
    (ws / "ds_badmeta" / "meta.json").write_text('{"format_version": 1, "scene": ')
    shutil.copytree(ws / "ds", ws / "ds_truncated")
    frame = ws / "ds_truncated" / "train" / "000001.npz"
    frame.write_bytes(frame.read_bytes()[:300])

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        train(tiny_config(ws / "ds", max_steps=1, max_val_frames=1), ws / "run", progress=False)
    finally:
        torch.set_num_threads(threads)
    shutil.copytree(ws / "run", ws / "run_badckpt")
    (ws / "run_badckpt" / "checkpoint.pt").write_bytes(b"\x80\x02 not a checkpoint")
    shutil.copytree(ws / "run", ws / "run_nodata")
    cfg = (ws / "run_nodata" / "config.json").read_text()
    (ws / "run_nodata" / "config.json").write_text(cfg.replace(str(ws / "ds"), str(ws / "gone")))

    (ws / "model_bad").mkdir()
    shutil.copy(DEFAULT_MODEL.parent / "model.json", ws / "model_bad" / "model.json")
    (ws / "model_bad" / "model_fp16.onnx").write_bytes(np.random.default_rng(0).bytes(2048))
    return ws


# -- the cases ---------------------------------------------------------------------------------------------------------
DATASET = (
    "gicore-dataset",
    "scene.toml",
    "--out",
    "out",
    "--train",
    "1",
    "--val",
    "0",
    "--resolution",
    "8",
    "--spp",
    "1",
    "--no-denoise",
)
TRAIN = ("gigan-train", "ds", "--out", "out", "--ngf", "4", "--max-steps", "1", "--no-progress")
CLIENT = (
    "gigan-client",
    "--scene",
    "scene.toml",
    "--frames",
    "1",
    "--resolution",
    "16",
    "--spp",
    "1",
    "--no-denoise",
    "--out",
    "out",
)

CASES = [
    # gicore-dataset: scene specs and meshes are checked before anything renders or is written
    case("gicore-dataset", "--out", "out", culprit="Missing argument 'scenes'", id="dataset-no-scenes"),
    case("gicore-dataset", "nope", "--out", "out", culprit="no scene spec 'nope'", id="dataset-unknown-scene"),
    case(
        "gicore-dataset", "broken.toml", "--out", "out", culprit="broken.toml: cannot parse", id="dataset-spec-syntax"
    ),
    case(
        "gicore-dataset",
        "bad_field.toml",
        "--out",
        "out",
        culprit="bad_field.toml: 1 invalid field(s): light.intensity",
        id="dataset-spec-field",
    ),
    case(
        "gicore-dataset",
        "bad_name.toml",
        "--out",
        "out",
        culprit="name: '../../x' is not a name",
        id="dataset-scene-name-path",
    ),
    case(
        "gicore-dataset",
        "empty_name.toml",
        "--out",
        "out",
        culprit="name: '' is not a name",
        id="dataset-scene-name-empty",
    ),
    case("gicore-dataset", "near.toml", "--out", "out", culprit="near = 1e-20", id="dataset-near-1e-20"),
    case(
        "gicore-dataset",
        "mesh_missing.toml",
        "--out",
        "out",
        culprit="meshes/missing.obj: not found",
        id="dataset-mesh-missing",
    ),
    case(
        "gicore-dataset",
        "mesh_empty.toml",
        "--out",
        "out",
        culprit="meshes/empty.obj: no triangles",
        id="dataset-mesh-empty",
    ),
    case(
        "gicore-dataset",
        "mesh_text.toml",
        "--out",
        "out",
        culprit="meshes/text.obj: no triangles",
        id="dataset-mesh-not-a-mesh",
    ),
    case(
        "gicore-dataset",
        "mesh_nan.toml",
        "--out",
        "out",
        culprit="meshes/nan.obj: 1 vertex(es) with NaN or Inf",
        id="dataset-mesh-nan-vertex",
    ),
    case(
        "gicore-dataset",
        "mesh_5.toml",
        "--out",
        "out",
        culprit="objects.0.mesh: Input is not a valid path",
        id="dataset-mesh-5",
    ),
    case(*DATASET, "--train", "0", "--val", "0", culprit="--train 0 --val 0", id="dataset-no-frames"),
    case(*DATASET, "--fov", "0", culprit="--fov = 0.0", id="dataset-fov-0"),
    case(*DATASET, "--fov", "-5", culprit="--fov = -5.0", id="dataset-fov-negative"),
    case(*DATASET, "--resolution", "0", culprit="--resolution = 0 is below 8", id="dataset-resolution-0"),
    case(*DATASET, "--spp", "0", culprit="--spp = 0 is below 1", id="dataset-spp-0"),
    # counts a user would accept (memory grew without bound before any frame), finite floats, seeds
    case(
        *DATASET, "--train", "1000000000000", culprit="--train = 1000000000000 is above 100000", id="dataset-train-huge"
    ),
    case(*DATASET, "--val", "1000000000000", culprit="--val = 1000000000000 is above 100000", id="dataset-val-huge"),
    case(*DATASET, "--spp", "1000000", culprit="--spp = 1000000 is above 4096", id="dataset-spp-huge"),
    case(*DATASET, "--resolution", "4096", culprit="--resolution = 4096 is above 2048", id="dataset-resolution-4096"),
    case(*DATASET, "--fov", "inf", culprit="--fov = inf is not finite", id="dataset-fov-inf"),
    case(*DATASET, "--fov", "nan", culprit="--fov = nan is not finite", id="dataset-fov-nan"),
    case(*DATASET, "--seed", "-1", culprit="--seed = -1 is below 0", id="dataset-seed-negative"),
    case(*DATASET, "--workers", "100000", culprit="--workers = 100000 is above", id="dataset-workers-huge"),
    case(*DATASET, "--buffers", "gt,bogus", culprit="['bogus']", id="dataset-unknown-buffer"),
    case(*DATASET[:3], "afile", *DATASET[4:], culprit="afile/s", id="dataset-out-is-a-file"),
    case(
        *DATASET[:3],
        "rendered",
        *DATASET[4:],
        "--spp",
        "2",
        culprit="rendered/s holds a dataset made with other settings (spp 1 -> 2",
        id="dataset-other-settings",
    ),
    case(
        *DATASET[:3],
        "rendered",
        *DATASET[4:],
        culprit="another run holds rendered/s",
        id="dataset-folder-held",
        hold="rendered/s",
    ),
    # gigan-train: datasets, run folders and option values
    case("gigan-train", "--out", "out", culprit="no dataset folders given", id="train-no-datasets"),
    case("gigan-train", "nowhere", "--out", "out", culprit="nowhere/meta.json is missing", id="train-dataset-missing"),
    case(
        "gigan-train",
        "ds_badmeta",
        "--out",
        "out",
        culprit="ds_badmeta/meta.json is not a readable dataset description",
        id="train-meta-corrupt",
    ),
    case(
        "gigan-train",
        "ds_truncated",
        "--out",
        "out",
        "--no-progress",
        culprit="ds_truncated/train/000001.npz is corrupt or truncated",
        id="train-frame-truncated",
    ),
    case(
        "gigan-train",
        "rendered/s",
        "--out",
        "out",
        "--model",
        "deep_shading",
        culprit="the 'val' split of ['rendered/s'] has no frames",
        id="train-no-val-frames",
    ),
    case(*TRAIN[:3], "afile", *TRAIN[4:], culprit="--out afile is a file", id="train-out-is-a-file"),
    case(*TRAIN, "--ngf", "0", culprit="--ngf = 0 is below 1", id="train-ngf-0"),
    case(*TRAIN, "--lr", "0", culprit="--lr = 0.0", id="train-lr-0"),
    case(*TRAIN, "--lr", "inf", culprit="--lr = inf is not finite", id="train-lr-inf"),
    case(*TRAIN, "--lambda-l1", "nan", culprit="--lambda-l1 = nan is not finite", id="train-lambda-l1-nan"),
    case(*TRAIN, "--beta1", "1", culprit="--beta1 = 1.0 is not below 1.0", id="train-beta1-1"),
    case(*TRAIN, "--ngf", "1000000", culprit="--ngf = 1000000 is above 1024", id="train-ngf-huge"),
    case(
        *TRAIN,
        "--batch-size",
        "1000000000000",
        culprit="--batch-size = 1000000000000 is above 4096",
        id="train-batch-huge",
    ),
    case(*TRAIN, "--max-minutes", "-1", culprit="--max-minutes = -1.0", id="train-max-minutes-negative"),
    case(*TRAIN, "--model", "pix2pix", culprit="'--model'", id="train-unknown-model"),
    case(*TRAIN, "--buffers", "di,bogus", culprit="['bogus']", id="train-unknown-buffer"),
    case(
        *TRAIN,
        "--buffers",
        "di,position",
        culprit="['position'] cannot be network inputs",
        id="train-buffer-not-an-input",
    ),
    case(*TRAIN, "--crop", "64", culprit="crop 64 exceeds the frame size 32", id="train-crop-too-large"),
    case(*TRAIN[:3], "run", *TRAIN[4:], culprit="--out run already holds a run", id="train-rerun-refused"),
    case("gigan-train", "--out", "run", "--resume", "--ngf", "8", culprit="not ['ngf']", id="train-resume-changes-ngf"),
    case("gigan-train", "--out", "ds", "--resume", culprit="ds/config.json is missing", id="train-resume-not-a-run"),
    case(
        "gigan-train",
        "--out",
        "run_badckpt",
        "--resume",
        culprit="run_badckpt/checkpoint.pt is not a readable checkpoint",
        id="train-checkpoint-corrupt",
    ),
    case("gigan-train", "--out", "run", "--resume", culprit="another run holds run", id="train-run-held", hold="run"),
    # gigan-export
    case("gigan-export", "nowhere", "--out", "out", culprit="nowhere/config.json is missing", id="export-run-missing"),
    case(
        "gigan-export",
        "run_badckpt",
        "--out",
        "out",
        culprit="run_badckpt/checkpoint.pt is not a readable checkpoint",
        id="export-checkpoint-corrupt",
    ),
    case("gigan-export", "run", "--out", "afile", culprit="--out afile is a file", id="export-out-is-a-file"),
    case("gigan-export", "run", "--out", "out", "--opset", "5", culprit="--opset = 5 is below 17", id="export-opset-5"),
    case(
        "gigan-export", "run", "--out", "out", "--opset", "30", culprit="--opset = 30 is above 20", id="export-opset-30"
    ),
    case(
        "gigan-export",
        "run",
        "--out",
        "out",
        "--calibration-frames",
        "1000000000000",
        culprit="--calibration-frames = 1000000000000 is above 100000",
        id="export-calibration-frames-huge",
    ),
    case(
        "gigan-export",
        "run_nodata",
        "--out",
        "out",
        "--int8",
        culprit="int8 export calibrates on the run's train frames",
        id="export-int8-without-data",
    ),
    case("gigan-export", "run", "--out", "out", culprit="another run holds out", id="export-out-held", hold="out"),
    # gigan-client
    case(*CLIENT, "--gi-fov", "0", culprit="--gi-fov = 0.0", id="client-gi-fov-0"),
    case(*CLIENT, "--local-fov", "0", culprit="--local-fov = 0.0", id="client-local-fov-0"),
    case(*CLIENT, "--local-fov", "180", culprit="--local-fov = 180.0", id="client-local-fov-180"),
    case(*CLIENT, "--resolution", "0", culprit="--resolution = 0 is below 8", id="client-resolution-0"),
    case(
        *CLIENT,
        "--frames",
        "1000000000000",
        culprit="--frames = 1000000000000 is above 100000",
        id="client-frames-huge",
    ),
    case(
        *CLIENT,
        "--orbit-frames",
        "1000000000000",
        culprit="--orbit-frames = 1000000000000 is above 100000",
        id="client-orbit-frames-huge",
    ),
    case(*CLIENT, "--spp", "1000000", culprit="--spp = 1000000 is above 4096", id="client-spp-huge"),
    case(*CLIENT, "--tau", "nan", culprit="--tau = nan is not finite", id="client-tau-nan"),
    case(*CLIENT, "--gi-fov", "inf", culprit="--gi-fov = inf is not finite", id="client-gi-fov-inf"),
    case(*CLIENT, "--seed", "-1", culprit="--seed = -1 is below 0", id="client-seed-negative"),
    case(*CLIENT, "--threads", "0", culprit="--threads = 0 is below 1", id="client-threads-0"),
    case(*CLIENT, "-k", "0", culprit="--every = 0 is below 1", id="client-every-0"),
    case(*CLIENT, "--warp", "bilinear", culprit="'--warp'", id="client-unknown-warp"),
    case(*CLIENT[:2], "nope", *CLIENT[3:], culprit="no scene spec 'nope'", id="client-unknown-scene"),
    case(*CLIENT[:2], "bad_field.toml", *CLIENT[3:], culprit="light.intensity", id="client-spec-field"),
    case(*CLIENT[:2], "mesh_nan.toml", *CLIENT[3:], culprit="meshes/nan.obj", id="client-mesh-nan-vertex"),
    case(
        *CLIENT,
        "--gi-source",
        "model",
        "--model",
        "missing.onnx",
        culprit="--model missing.onnx",
        id="client-model-missing",
    ),
    case(
        *CLIENT,
        "--gi-source",
        "model",
        "--model",
        "model_bad/model_fp16.onnx",
        culprit="model_bad/model_fp16.onnx is not a loadable ONNX model",
        id="client-model-corrupt",
    ),
    case(*CLIENT[:-1], "afile", culprit="--out afile is a file", id="client-out-is-a-file"),
]


@pytest.fixture(scope="module")
def outcomes(workspace: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Outcome]:
    """Every row of ``CASES`` run once, each in its own copy of the workspace, three at a time."""
    from gicore.fileio import exclusive_run

    def run_case(row) -> tuple[str, Outcome]:
        argv, _, hold = row.values
        cwd = tmp_path_factory.mktemp("case")
        shutil.copytree(workspace, cwd, dirs_exist_ok=True)
        with exclusive_run(cwd / hold) if hold else nullcontext():
            return row.id, run_script(argv, cwd)

    with ThreadPoolExecutor(3) as pool:
        return dict(pool.map(run_case, CASES))


@pytest.mark.slow  # ~90 subprocesses: about two minutes on 2 cores
@pytest.mark.parametrize("argv,culprit,hold", CASES)
def test_bad_input_is_one_clean_error_line(
    outcomes: dict[str, Outcome], request: pytest.FixtureRequest, argv: list[str], culprit: str, hold: str | None
):
    outcome = outcomes[request.node.callspec.id]
    assert list(outcome.argv) == argv
    check_user_error(outcome, culprit)


@pytest.mark.slow
def test_debug_shows_the_traceback(workspace: Path):
    """--debug is the way to a traceback for a user error."""
    proc = subprocess.run(
        [str(BIN / "gicore-dataset"), "nope", "--debug"],
        cwd=workspace,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 1 and "Traceback" in proc.stderr and "SceneSpecError" in proc.stderr


# -- Ctrl-C ----------------------------------------------------------------------------------------------------------
def interrupt_when(argv: list[str], cwd: Path, ready) -> subprocess.CompletedProcess:
    """Start console script ``argv``, send it SIGINT (Ctrl-C) once ``ready()`` holds, and wait for it."""
    import signal
    import time

    proc = subprocess.Popen(
        [str(BIN / argv[0]), *argv[1:]], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + TIMEOUT_S
    while not ready() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=TIMEOUT_S)
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)


@pytest.mark.slow
def test_interrupted_dataset_keeps_whole_frames_and_resumes(workspace: Path, tmp_path: Path):
    from gicore.dataset import frame_paths, load_frame
    from gicore.fileio import TMP_MARKER

    shutil.copytree(workspace, tmp_path, dirs_exist_ok=True)
    argv = [
        "gicore-dataset",
        "scene.toml",
        "--out",
        "ds_int",
        "--train",
        "200",
        "--val",
        "0",
        "--resolution",
        "8",
        "--spp",
        "1",
        "--no-denoise",
    ]
    frames = tmp_path / "ds_int" / "s" / "train"
    done = interrupt_when(argv, tmp_path, lambda: len(list(frames.glob("*.npz"))) >= 3)
    assert done.returncode == 130, done.stderr
    assert (
        "Traceback" not in done.stderr
        and "interrupted: finished frames are kept: run the same command again" in done.stderr
    )
    kept = sorted(frames.glob("*.npz"))
    assert 3 <= len(kept) < 200, "the run should have stopped part-way"
    assert (
        not list((tmp_path / "ds_int").rglob(f"*{TMP_MARKER}*")) and not (tmp_path / "ds_int" / "s" / ".lock").exists()
    )
    for path in kept:
        load_frame(path)  # every frame left behind is whole
    mtimes = {p: p.stat().st_mtime_ns for p in kept}
    rerun = subprocess.run(
        [str(BIN / argv[0]), *argv[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=TIMEOUT_S
    )
    assert rerun.returncode == 0, rerun.stderr
    assert len(frame_paths(tmp_path / "ds_int" / "s", "train")) == 200
    assert all(p.stat().st_mtime_ns == t for p, t in mtimes.items()), "a kept frame was rendered again"


@pytest.mark.slow
def test_interrupted_training_resumes_from_its_checkpoint(workspace: Path, tmp_path: Path):
    import csv

    shutil.copytree(workspace, tmp_path, dirs_exist_ok=True)
    argv = [
        "gigan-train",
        "ds",
        "--out",
        "run_int",
        "--ngf",
        "4",
        "--batch-size",
        "1",
        "--checkpoint-every",
        "1",
        "--no-progress",
    ]
    checkpoint = tmp_path / "run_int" / "checkpoint.pt"
    done = interrupt_when(argv, tmp_path, checkpoint.is_file)
    assert done.returncode == 130, done.stderr
    assert "Traceback" not in done.stderr and "run the same command with --resume" in done.stderr
    assert sorted(p.name for p in (tmp_path / "run_int").iterdir()) == ["checkpoint.pt", "config.json", "metrics.csv"]
    resumed = subprocess.run(
        [str(BIN / "gigan-train"), "--out", "run_int", "--resume", "--epochs", "2", "--no-progress"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert resumed.returncode == 0, resumed.stderr
    assert "stopped (epochs) at step 4, epoch 2" in resumed.stdout
    with (tmp_path / "run_int" / "metrics.csv").open() as f:
        val_steps = [int(r["step"]) for r in csv.DictReader(f) if r["split"] == "val" and r["metric"] == "ssim"]
    assert val_steps == sorted(set(val_steps)), f"validation rows repeated after the resume: {val_steps}"
