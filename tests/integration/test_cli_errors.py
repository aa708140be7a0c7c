"""Every console script fails cleanly on bad input (docs/architecture.md, Errors).

Each row runs one console script in its own copy of a scratch workspace that holds valid and broken inputs
(see :func:`workspace`), and checks the policy: exit status 2, exactly one ``error:`` line on stderr that
names the culprit (the file or field at fault), no traceback, and nothing written, changed or left behind
in the workspace. Rows run the script's ``main`` in this process (:func:`run_main`); one row per script
(``process=True``) runs the installed script as a subprocess, so its entry point, exit status and streams
are those of a real process.

To cover a new script, add rows to ``CASES`` with :func:`case` (argv relative to the workspace; put new
inputs in :func:`workspace`), or call :func:`assert_user_error` from your own test module.
"""

from __future__ import annotations

import shutil
import signal
import sys
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import pytest

from tests.helpers.cli import check_user_error, run_main, run_script, script_main, signal_when


def case(*argv: str, culprit: str, id: str, hold: str | None = None, process: bool = False):
    """A row of ``CASES``: ``hold`` names a workspace folder that another run holds meanwhile; ``process``
    runs the installed script as a subprocess instead of its ``main`` in this process."""
    return pytest.param(list(argv), culprit, hold, process, id=id)


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

    # A one-step run of the smallest network: each case copies the workspace, so its checkpoint stays small.
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
    case("gicore-dataset", "--out", "out", culprit="no scenes given", id="dataset-no-scenes"),
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
        process=True,
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
    case(*TRAIN[:3], "ds", *TRAIN[4:], culprit="--out ds is not a training run (it holds", id="train-out-not-a-run"),
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
    case(
        "gigan-train",
        "--out",
        "run",
        "--resume",
        culprit="another run holds run",
        id="train-run-held",
        process=True,
        hold="run",
    ),
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
    case(
        "gigan-export",
        "run",
        "--out",
        "out",
        culprit="another run holds out",
        id="export-out-held",
        process=True,
        hold="out",
    ),
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
    case(
        *CLIENT,
        "--warp",
        "bilinear",
        culprit="'--warp': 'bilinear' is not one of 'structure', 'none'",
        id="client-unknown-warp",
        process=True,
    ),
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


@pytest.mark.parametrize("argv,culprit,hold,process", CASES)
def test_bad_input_is_one_clean_error_line(
    workspace: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
    argv: list[str],
    culprit: str,
    hold: str | None,
    process: bool,
):
    from gicore.fileio import exclusive_run

    shutil.copytree(workspace, tmp_path, dirs_exist_ok=True)
    with exclusive_run(tmp_path / hold) if hold else nullcontext():
        outcome = run_script(argv, tmp_path) if process else run_main(argv, tmp_path, monkeypatch, capfd)
    check_user_error(outcome, culprit)


def test_a_new_runs_out_may_hold_what_gigan_train_writes() -> None:
    from gigan_local import train
    from gigan_local.train_cli import RUN_FILES

    assert {train.CHECKPOINT, train.METRICS} <= RUN_FILES


def test_every_script_has_a_process_row():
    """Each console script of ``CASES`` runs once as a real process."""
    scripts = {row.values[0][0] for row in CASES}
    assert scripts == {row.values[0][0] for row in CASES if row.values[3]}


def test_debug_shows_the_traceback(workspace: Path, monkeypatch: pytest.MonkeyPatch):
    """--debug is the way to a traceback for a user error: the error leaves ``main`` uncaught, so the
    interpreter prints its traceback (and exits 1)."""
    from gicore.scene import SceneSpecError

    monkeypatch.chdir(workspace)
    monkeypatch.setattr(sys, "argv", ["gicore-dataset", "nope", "--debug"])
    with pytest.raises(SceneSpecError, match="no scene spec 'nope'"):
        script_main("gicore-dataset")()


# -- Ctrl-C: the interrupted run is a process; the run that resumes it runs in this process -------------------------
@pytest.mark.slow
def test_interrupted_dataset_keeps_whole_frames_and_resumes(
    workspace: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
):
    from gicore.dataset import frame_paths, load_frame
    from gicore.fileio import TMP_MARKER

    shutil.copytree(workspace, tmp_path, dirs_exist_ok=True)
    argv = [*DATASET[:3], "ds_int", "--train", "200", *DATASET[6:]]
    frames = tmp_path / "ds_int" / "s" / "train"
    status, err = signal_when(argv, tmp_path, lambda _: len(list(frames.glob("*.npz"))) >= 3, signal.SIGINT)
    assert status == 130, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines[-1] == "interrupted: finished frames are kept: run the same command again to render the rest", err
    assert "Traceback" not in err
    kept = sorted(frames.glob("*.npz"))
    assert 3 <= len(kept) < 200, "the run should have stopped part-way"
    assert (
        not list((tmp_path / "ds_int").rglob(f"*{TMP_MARKER}*")) and not (tmp_path / "ds_int" / "s" / ".lock").exists()
    )
    for path in kept:
        load_frame(path)  # every frame left behind is whole
    mtimes = {p: p.stat().st_mtime_ns for p in kept}
    rerun = run_main(argv, tmp_path, monkeypatch, capfd)
    assert rerun.returncode == 0, rerun.stderr
    assert len(frame_paths(tmp_path / "ds_int" / "s", "train")) == 200
    assert all(p.stat().st_mtime_ns == t for p, t in mtimes.items()), "a kept frame was rendered again"


@pytest.mark.slow
def test_interrupted_training_resumes_from_its_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
):
    import csv

    from tests.helpers.training import make_dataset

    make_dataset(tmp_path / "ds", n_train=2, n_val=1)
    argv = [*TRAIN[:3], "run_int", "--ngf", "4", "--batch-size", "1", "--checkpoint-every", "1", "--no-progress"]
    checkpoint = tmp_path / "run_int" / "checkpoint.pt"
    status, err = signal_when(argv, tmp_path, lambda _: checkpoint.is_file(), signal.SIGINT)
    assert status == 130, err
    assert "Traceback" not in err and "run the same command with --resume" in err
    assert sorted(p.name for p in (tmp_path / "run_int").iterdir()) == ["checkpoint.pt", "config.json", "metrics.csv"]
    resume = ["gigan-train", "--out", "run_int", "--resume", "--epochs", "2", "--no-progress"]
    resumed = run_main(resume, tmp_path, monkeypatch, capfd)
    assert resumed.returncode == 0, resumed.stderr
    assert "stopped (epochs) at step 4, epoch 2" in resumed.stdout  # batch 1: a step per frame and epoch
    with (tmp_path / "run_int" / "metrics.csv").open() as f:
        val_steps = [int(r["step"]) for r in csv.DictReader(f) if r["split"] == "val" and r["metric"] == "ssim"]
    assert val_steps == sorted(set(val_steps)), f"validation rows repeated after the resume: {val_steps}"
