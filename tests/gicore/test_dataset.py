"""Dataset format and builder: determinism, resumability, settings guard, buffers, light records
(docs/architecture.md, Dataset folder)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gicore.buffers import STORAGE_DTYPE
from gicore.camera import Camera
from gicore.dataset import DatasetMeta, frame_paths, load_frame, read_meta, save_frame
from gicore.dataset_cli import DatasetConfig, build_dataset, plan_frames
from gicore.error_policy import UserError
from gicore.paths import frame_seed
from tests.helpers.dataset import npz_arrays

RES = 24
CFG = DatasetConfig(n_train=2, n_val=1, resolution=RES, spp=4, denoise=False, seed=0)


@pytest.fixture(scope="module")
def moving_spec(make_spec):
    return make_spec(light={"amplitude": [0.6, 0.3], "period": [40.0, 60.0]})


@pytest.fixture(scope="module")
def static_spec(make_spec):
    return make_spec(light={"amplitude": [0.0, 0.0]})


@pytest.fixture(scope="module")
def base_dataset(moving_spec, tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "a"
    meta = build_dataset(moving_spec, root, CFG, progress=False)
    return root, meta


# -- determinism -------------------------------------------------------------------------------------------
def test_layout_and_meta(base_dataset):
    root, meta = base_dataset
    assert sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()) == [
        "meta.json",
        "train/000000.npz",
        "train/000001.npz",
        "val/000000.npz",
    ]
    back = read_meta(root)
    assert back.settings() == meta.settings()
    assert [(f.split, f.index) for f in back.frames] == [("train", 0), ("train", 1), ("val", 0)]
    assert [p.name for p in frame_paths(root, "train")] == ["000000.npz", "000001.npz"]
    # The recorded matrices are the cameras' GL matrices.
    for rec in back.frames:
        cam = Camera.from_dict(rec.camera)
        np.testing.assert_allclose(rec.view, cam.view())
        np.testing.assert_allclose(rec.proj, cam.proj())
        assert cam.width == cam.height == RES
    # Validation cameras are held out: not on the training path.
    val_origin = np.array(back.split_frames("val")[0].camera["origin"])
    assert all(np.linalg.norm(val_origin - np.array(f.camera["origin"])) > 1e-3 for f in back.split_frames("train"))


def test_stored_buffers_and_precision(base_dataset):
    root, meta = base_dataset
    frame = npz_arrays(root)["train/000000.npz"]
    assert list(frame) == list(CFG.buffers)
    for name, arr in frame.items():
        assert arr.dtype == STORAGE_DTYPE[name], name
        assert arr.shape[:2] == (RES, RES)
        assert np.all(np.isfinite(arr))
    loaded = load_frame(root / "train/000000.npz")
    assert all(a.dtype == np.float32 for a in loaded.values())
    assert list(load_frame(root / "train/000000.npz", ["gt"])) == ["gt"]


def test_same_seed_gives_identical_arrays(base_dataset, moving_spec, tmp_path):
    root_a, meta_a = base_dataset
    root_b = tmp_path / "b"
    meta_b = build_dataset(moving_spec, root_b, CFG, progress=False)
    assert meta_a.to_dict() == meta_b.to_dict()
    a, b = npz_arrays(root_a), npz_arrays(root_b)
    assert list(a) == list(b)
    for file in a:
        for name in a[file]:
            np.testing.assert_array_equal(a[file][name], b[file][name], err_msg=f"{file}:{name}")


def test_different_seed_gives_different_noise(base_dataset, moving_spec, tmp_path, renderer):
    root_a, _ = base_dataset
    root_c = tmp_path / "c"
    build_dataset(moving_spec, root_c, replace(CFG, seed=1), progress=False)
    a, c = npz_arrays(root_a), npz_arrays(root_c)
    for file in a:
        assert not np.array_equal(a[file]["gt"], c[file]["gt"]), file
    # The per-frame render seed differs with the dataset seed, split and index ...
    seeds = {frame_seed(s, split, i) for s in (0, 1) for split in ("train", "val") for i in range(3)}
    assert len(seeds) == 12
    # ... and for one and the same camera, different frame seeds give different GT noise.
    cam = Camera.from_dict(
        read_meta(root_a).frames[0].camera | {"width": renderer.resolution, "height": renderer.resolution}
    )
    g0 = renderer.render_frame(cam, buffers=("gt",), spp=4, seed=frame_seed(0, "train", 0))["gt"]
    g1 = renderer.render_frame(cam, buffers=("gt",), spp=4, seed=frame_seed(1, "train", 0))["gt"]
    assert not np.array_equal(g0, g1)


# -- light records ------------------------------------------------------------------------------------------
def test_static_light_has_no_light_schedule(static_spec, tmp_path):
    root = tmp_path / "static"
    build_dataset(static_spec, root, replace(CFG, n_train=2, n_val=1), progress=False)
    raw = json.loads((root / "meta.json").read_text())
    assert raw["frames"] and all("light" not in f for f in raw["frames"])
    assert "light" not in json.dumps(raw["frames"])
    assert all(f.light is None for f in read_meta(root).frames)


def test_moving_light_is_recorded(base_dataset, moving_spec):
    root, _ = base_dataset
    raw = json.loads((root / "meta.json").read_text())
    lights = [f["light"] for f in raw["frames"]]
    assert all(len(light) == 3 for light in lights)
    assert lights[0] != lights[1]  # it moves between training frames
    assert all(light[2] == moving_spec.light.position[2] for light in lights)  # along x and y only


def test_plan_frames_light_only_when_moving(static_spec, moving_spec):
    assert all(r.light is None for r in plan_frames(static_spec, CFG))
    assert all(r.light is not None for r in plan_frames(moving_spec, CFG))


# -- resumability and settings guard ----------------------------------------------------------------------------
def test_resume_rerenders_only_missing_frames(moving_spec, tmp_path):
    root = tmp_path / "resume"
    cfg = replace(CFG, n_train=3, n_val=0)
    build_dataset(moving_spec, root, cfg, progress=False)
    files = sorted(root.rglob("*.npz"))
    assert len(files) == 3
    before = {p: p.stat().st_mtime_ns for p in files}
    original = npz_arrays(root)
    victim = root / "train/000001.npz"
    victim.unlink()
    with pytest.raises(UserError, match=r"1 frame\(s\) of .* are missing.*gicore-dataset"):
        frame_paths(root, "train")
    build_dataset(moving_spec, root, cfg, progress=False)
    assert victim.is_file()
    for p, mtime in before.items():
        if p != victim:
            assert p.stat().st_mtime_ns == mtime, f"{p} was rewritten"
    # The re-rendered frame is bit-identical to the lost one (per-frame seeds).
    redone = npz_arrays(root)
    for name, arr in original["train/000001.npz"].items():
        np.testing.assert_array_equal(arr, redone["train/000001.npz"][name])
    assert not list(root.rglob("*.tmp*")), "no temporary files left behind"
    # A complete dataset is a no-op rerun.
    mtimes = {p: p.stat().st_mtime_ns for p in root.rglob("*.npz")}
    build_dataset(moving_spec, root, cfg, progress=False)
    assert {p: p.stat().st_mtime_ns for p in root.rglob("*.npz")} == mtimes


@pytest.mark.parametrize(
    "change",
    [
        pytest.param(dict(spp=8), id="spp"),
        pytest.param(dict(resolution=16), id="resolution"),
        pytest.param(dict(seed=3), id="seed"),
        pytest.param(dict(buffers=("gt", "di")), id="buffers"),
        pytest.param(dict(denoise=True), id="denoise"),
    ],
)
def test_refuses_to_mix_settings(base_dataset, moving_spec, change):
    root, _ = base_dataset
    before = (root / "meta.json").read_text()
    with pytest.raises(UserError, match="other settings") as info:
        build_dataset(moving_spec, root, replace(CFG, **change), progress=False)
    assert next(iter(change)) in str(info.value)  # the message names the setting that differs
    assert (root / "meta.json").read_text() == before


@pytest.mark.parametrize(
    "change",
    [
        pytest.param(dict(n_train=3), id="n_train"),
        pytest.param(dict(fov=40.0), id="fov"),
    ],
)
def test_changed_frame_plan_never_leaves_stale_frames(moving_spec, tmp_path, change):
    """Frame i's camera depends on the frame count and FOV, so a rerun with another count or FOV must
    either be refused or re-render every frame whose record changed: never keep an image rendered
    for another camera under the new meta.json."""
    root = tmp_path / "plan"
    build_dataset(moving_spec, root, CFG, progress=False)
    new_cfg = replace(CFG, **change)
    try:
        build_dataset(moving_spec, root, new_cfg, progress=False)
    except UserError as err:
        assert "settings" in str(err)
        return
    fresh = tmp_path / "fresh"
    build_dataset(moving_spec, fresh, new_cfg, progress=False)
    assert read_meta(root).to_dict() == read_meta(fresh).to_dict()
    a, b = npz_arrays(root), npz_arrays(fresh)
    assert list(a) == list(b)
    for file in b:
        for name in b[file]:
            np.testing.assert_array_equal(a[file][name], b[file][name], err_msg=f"stale {file}:{name}")


def test_refuses_another_scene(base_dataset, make_spec):
    root, _ = base_dataset
    with pytest.raises(UserError, match="other settings.*scene differs"):
        build_dataset(
            make_spec(light={"intensity": 3.0, "amplitude": [0.6, 0.3], "period": [40.0, 60.0]}),
            root,
            CFG,
            progress=False,
        )


# -- buffers ------------------------------------------------------------------------------------------------------
def test_only_requested_buffers_are_stored(moving_spec, tmp_path):
    root = tmp_path / "subset"
    cfg = replace(CFG, n_train=1, n_val=0, buffers=("gt", "depth"))
    meta = build_dataset(moving_spec, root, cfg, progress=False)
    assert meta.buffers == ["gt", "depth"]
    with np.load(root / "train/000000.npz") as data:
        assert sorted(data.files) == ["depth", "gt"]
        assert data["depth"].shape == (RES, RES, 1)
    with pytest.raises(UserError, match=r"000000\.npz lacks buffer\(s\) \['albedo'\]"):
        load_frame(root / "train/000000.npz", ["gt", "albedo"])
    with pytest.raises(UserError, match="unknown buffer"):
        load_frame(root / "train/000000.npz", ["specular"])


DENOISE_SCRIPT = """
import sys
from pathlib import Path

import numpy as np

from gicore.dataset import load_frame
from gicore.dataset_cli import DatasetConfig, build_dataset
from gicore.paths import camera_path
from gicore.render import Renderer
from gicore.scene import SceneSpec


def main(mesh, out):
    spec = SceneSpec.from_dict({"name": "d", "objects": [{"name": "ball", "mesh": mesh}],
                                "light": {"position": [0.8, 2.6, 1.2], "intensity": 12.0}})
    # Denoising needs albedo/normal internally, but only gt and depth are asked for.
    cfg = DatasetConfig(n_train=1, n_val=0, resolution=24, spp=2, denoise=True, buffers=("gt", "depth"))
    build_dataset(spec, out / "a", cfg, progress=False)
    with np.load(out / "a/train/000000.npz") as d:
        assert sorted(d.files) == ["depth", "gt"], d.files
        assert np.all(np.isfinite(d["gt"]))
    print("built-1", flush=True)
    # The same process now denoises in-process (as a bench or client would) ...
    r = Renderer(spec, 24)
    gt = r.render_frame(camera_path(spec, 1, resolution=24)[0], buffers=("gt",), spp=2, denoise=True)["gt"]
    assert gt.shape == (24, 24, 3) and np.all(np.isfinite(gt))
    print("denoised-in-process", flush=True)
    # ... and then builds another dataset with denoising workers.
    build_dataset(spec, out / "b", cfg, progress=False)
    a, b = load_frame(out / "a/train/000000.npz")["gt"], load_frame(out / "b/train/000000.npz")["gt"]
    np.testing.assert_array_equal(a, b)
    print("built-2", flush=True)


if __name__ == "__main__":
    main(sys.argv[1], Path(sys.argv[2]))
"""


def test_denoised_dataset_and_build_after_in_process_denoise(sphere_mesh_path, tmp_path):
    """Denoised GT in worker processes, also when the calling process has used the denoiser itself.

    Runs in a subprocess with a timeout (in its own process group, killed on timeout), because a
    worker forked from a process whose OIDN/Dr.Jit thread pools are running can deadlock.
    """
    import os
    import signal
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-c", DENOISE_SCRIPT, str(sphere_mesh_path), str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        cwd=Path(__file__).resolve().parents[2],
    )
    try:
        out, _ = proc.communicate(timeout=240)  # a hang guard: the work takes seconds
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail(f"build_dataset hung (deadlocked worker?); progress before the hang: {out.split()!r}")
    assert proc.returncode == 0, out
    assert out.split()[-3:] == ["built-1", "denoised-in-process", "built-2"], out


def test_unknown_buffer_rejected_before_rendering(moving_spec, tmp_path):
    with pytest.raises(UserError, match="bogus"):
        build_dataset(moving_spec, tmp_path / "x", replace(CFG, buffers=("gt", "bogus")), progress=False)
    assert not (tmp_path / "x").exists()


def test_save_frame_validation(tmp_path):
    with pytest.raises(ValueError, match="NaN"):
        save_frame(tmp_path / "f.npz", {"gt": np.full((4, 4, 3), np.nan, np.float32)})
    with pytest.raises(ValueError, match="depth"):
        save_frame(tmp_path / "f.npz", {"depth": np.zeros((4, 4, 3), np.float32)})
    with pytest.raises(UserError, match="unknown buffer"):
        save_frame(tmp_path / "f.npz", {"specular": np.zeros((4, 4, 3), np.float32)})
    assert not (tmp_path / "f.npz").exists()
    pos = np.random.default_rng(0).normal(size=(4, 4, 3)).astype(np.float32) * 1e3 + 1e-3
    save_frame(tmp_path / "f.npz", {"position": pos, "mask": np.ones((4, 4, 1), np.float32)})
    back = load_frame(tmp_path / "f.npz")
    np.testing.assert_array_equal(back["position"], pos)  # float32: reprojection needs it exact
    with pytest.raises(UserError, match=r"nope\.npz is missing"):
        load_frame(tmp_path / "nope.npz")


def test_read_meta_errors(tmp_path):
    with pytest.raises(UserError, match="meta.json is missing"):
        read_meta(tmp_path)
    (tmp_path / "meta.json").write_text(json.dumps({"format_version": 999}))
    with pytest.raises(
        UserError, match=r"meta\.json is not a readable dataset description \(dataset format_version 999"
    ):
        read_meta(tmp_path)
    with pytest.raises(ValueError, match="split"):
        DatasetMeta({}, 8, 1, False, 0, ["gt"]).split_frames("test")


# -- bad files and bad settings are user errors naming the culprit -----------------------------------------------
@pytest.mark.parametrize(
    "damage",
    [
        pytest.param(lambda b: b[: len(b) // 2], id="truncated"),
        pytest.param(lambda b: b"", id="empty"),
        pytest.param(lambda b: b"not an archive at all " * 20, id="garbage"),
        pytest.param(lambda b: b[:200] + bytes(60) + b[260:], id="zeroed_bytes"),
    ],
)
def test_corrupt_frame_names_the_file(base_dataset, tmp_path, damage):
    root, _ = base_dataset
    bad = tmp_path / "000000.npz"
    bad.write_bytes(damage((root / "train/000000.npz").read_bytes()))
    with pytest.raises(UserError, match=r"000000\.npz is corrupt or truncated") as info:
        load_frame(bad)
    assert "pickle" not in str(info.value)  # never a hint to load untrusted pickles


@pytest.mark.parametrize(
    "text,reason",
    [
        pytest.param("{not json", "Expecting property name", id="syntax"),
        pytest.param("[1, 2]", "format_version None", id="not_an_object"),
        pytest.param(json.dumps({"format_version": 1, "scene": {}}), "lacks field", id="missing_fields"),
    ],
)
def test_corrupt_meta_names_the_file(tmp_path, text, reason):
    (tmp_path / "meta.json").write_text(text)
    with pytest.raises(UserError, match=rf"{tmp_path}/meta\.json is not a readable dataset description \(.*{reason}"):
        read_meta(tmp_path)


def test_meta_with_an_unknown_field_is_refused(base_dataset, tmp_path):
    root, _ = base_dataset
    doc = json.loads((root / "meta.json").read_text()) | {"exposure": 2.0}
    (tmp_path / "meta.json").write_text(json.dumps(doc))
    with pytest.raises(UserError, match=r"unknown dataset meta config field\(s\) \['exposure'\]"):
        read_meta(tmp_path)


@pytest.mark.parametrize(
    "change,culprit",
    [
        pytest.param(dict(n_train=0, n_val=0), "--train 0 --val 0", id="no_frames"),
        pytest.param(dict(fov=0.0), "--fov", id="fov_0"),
        pytest.param(dict(fov=-30.0), "--fov", id="fov_negative"),
        pytest.param(dict(fov=180.0), "--fov", id="fov_180"),
        pytest.param(dict(resolution=0), "--resolution = 0", id="resolution_0"),
        pytest.param(dict(spp=0), "--spp = 0", id="spp_0"),
    ],
)
def test_bad_dataset_settings_are_refused_before_anything_is_written(tmp_path, change, culprit):
    with pytest.raises(UserError, match=culprit):
        DatasetConfig(**change)


def test_zero_fov_is_not_the_default(moving_spec):
    """Only an absent FOV means the scene's: an explicit FOV reaches every camera of the plan."""
    assert {r.camera["fov"] for r in plan_frames(moving_spec, CFG)} == {moving_spec.camera.gi_fov}
    assert {r.camera["fov"] for r in plan_frames(moving_spec, replace(CFG, fov=1.0))} == {1.0}


def test_second_run_into_one_folder_is_refused(moving_spec, tmp_path):
    from gicore.fileio import exclusive_run

    root = tmp_path / "held"
    with exclusive_run(root):  # as a concurrent gicore-dataset run holds it
        with pytest.raises(UserError, match=f"another run holds {root}"):
            build_dataset(moving_spec, root, CFG, progress=False)
        assert not (root / "meta.json").exists()


def test_temporaries_of_a_killed_run_are_swept(moving_spec, tmp_path):
    from gicore.fileio import TMP_MARKER

    root = tmp_path / "swept"
    build_dataset(moving_spec, root, replace(CFG, n_train=1, n_val=0), progress=False)
    leftovers = [root / f"meta.json{TMP_MARKER}abc", root / "train" / f"000001.npz{TMP_MARKER}xyz"]
    for path in leftovers:
        path.write_bytes(b"half a frame")
    build_dataset(moving_spec, root, replace(CFG, n_train=1, n_val=0), progress=False)
    assert not any(p.exists() for p in leftovers)
    assert sorted(p.name for p in root.rglob("*")) == ["000000.npz", "meta.json", "train"]


def test_two_writers_of_one_frame_do_not_share_a_temporary_file(tmp_path):
    """A second writer of the same frame (a concurrent run) starts while the first is mid-write: with a
    shared temporary name one would rename the other's half-written file away."""
    from gicore.fileio import atomic_write

    target = tmp_path / "000000.npz"
    gt = np.ones((4, 4, 3), np.float32)

    def outer(handle):
        handle.write(b"first writer, partial ")
        save_frame(target, {"gt": gt * 2})  # the other writer runs to completion meanwhile
        handle.write(b"and done")

    atomic_write(target, outer)
    assert target.read_bytes() == b"first writer, partial and done"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["000000.npz"]


# -- the inputs' renderer --------------------------------------------------------------------------------------------
def _no_gl(monkeypatch) -> None:
    """Make this process's GL context unavailable, as on a machine without EGL."""
    import gicore.gl.context as context

    monkeypatch.setattr(context, "_context", None)
    monkeypatch.setattr(context, "_failure", "no EGL display here")


def test_gl_inputs_with_mitsuba_gt(base_dataset, moving_spec, tmp_path):
    """--renderer gl: the inputs are the GL renderer's (what a gl client feeds the model, at its level of detail),
    the GT is the Mitsuba dataset's to the bit (same seeds); meta.json records both, and render_inputs re-renders
    either dataset's inputs exactly."""
    from gicore.dataset_cli import FrameRenderer, render_inputs
    from gicore.gl import gl_available

    if not gl_available()[0]:
        pytest.skip(f"no OpenGL context: {gl_available()[1]}")
    mi_root, mi_meta = base_dataset
    root = tmp_path / "gl"
    meta = build_dataset(moving_spec, root, replace(CFG, renderer="gl"), progress=False)
    assert (meta.renderer, meta.lod) == ("gl", "auto") and (mi_meta.renderer, mi_meta.lod) == ("mitsuba", None)
    assert (read_meta(root).renderer, read_meta(root).lod) == ("gl", "auto")
    assert meta.inputs == ["di", "albedo", "normal", "depth"]
    gl, mi = FrameRenderer(moving_spec, RES, "gl"), FrameRenderer(moving_spec, RES, "mitsuba")
    for record in meta.frames:
        stored_gl, stored_mi = load_frame(root / record.file), load_frame(mi_root / record.file)
        np.testing.assert_array_equal(stored_gl["gt"], stored_mi["gt"])
        for renderer, stored in ((gl, stored_gl), (mi, stored_mi)):
            again = render_inputs(renderer, meta, record)
            assert sorted(again) == sorted(meta.inputs)
            for name, arr in again.items():
                np.testing.assert_array_equal(arr, stored[name], err_msg=f"{renderer.renderer} {record.file} {name}")
        # Two renderers of one view: the same surfaces (coverage), not the same pixels (GL's DI has no noise).
        assert np.mean((stored_gl["depth"] > 0) == (stored_mi["depth"] > 0)) > 0.95
        assert not np.array_equal(stored_gl["di"], stored_mi["di"])
    # A resume with the other renderer would mix two datasets: refused, naming the setting.
    with pytest.raises(UserError, match="renderer 'gl' -> 'mitsuba'"):
        build_dataset(moving_spec, root, CFG, progress=False)
    with pytest.raises(UserError, match="lod 'auto' -> 'full'"):
        build_dataset(moving_spec, root, replace(CFG, renderer="gl", gl_lod="full"), progress=False)


def test_gl_without_a_context_falls_back_to_mitsuba_and_says_so(moving_spec, tmp_path, monkeypatch, capsys):
    _no_gl(monkeypatch)
    cfg = replace(CFG, n_train=1, n_val=0, renderer="gl")
    meta = build_dataset(moving_spec, tmp_path / "d", cfg, progress=False)
    assert (meta.renderer, meta.lod) == ("mitsuba", None) and read_meta(tmp_path / "d").renderer == "mitsuba"
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["warning: renderer gl is unavailable, using mitsuba: no EGL display here"]


def test_renderer_options_are_checked_and_recorded(base_dataset, tmp_path):
    from typer.testing import CliRunner

    from gicore.dataset_cli import app
    from gicore.options import build_config

    assert build_config(DatasetConfig, {"renderer": "gl", "gl_lod": "3"}).gl_lod == "3"
    with pytest.raises(UserError, match="--renderer 'vulkan' is not one of gl, mitsuba"):
        DatasetConfig(renderer="vulkan")
    with pytest.raises(UserError, match="--gl-lod '9' is not one of"):
        DatasetConfig(gl_lod="9")
    for argv, option in ((["--renderer", "vulkan"], "--renderer"), (["--gl-lod", "-1"], "--gl-lod")):
        result = CliRunner().invoke(app, ["lung_plane", "--out", str(tmp_path / "never"), *argv])
        assert result.exit_code == 2 and option in result.output, result.output
    assert not (tmp_path / "never").exists()
    # meta.json: a dataset older than the field reads as mitsuba's; a bad renderer or lod is refused.
    root, _ = base_dataset
    doc = json.loads((root / "meta.json").read_text())
    doc.pop("renderer"), doc.pop("lod")
    assert (DatasetMeta.from_dict(doc).renderer, DatasetMeta.from_dict(doc).lod) == ("mitsuba", None)
    for bad in ({"renderer": "vulkan"}, {"renderer": "gl"}, {"lod": "auto"}):
        with pytest.raises(ValueError, match="renderer|lod"):
            DatasetMeta.from_dict(doc | bad)
