"""`bench inference`: the shipped generator's inference per backend with its error against onnxruntime fp32."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.inference_bench import BENCH, SHIPPED_FP32, TABLE, InferenceConfig, measure
from gicore.error_policy import UserError
from gicore.present import write_files
from gicore.present.markdown import table_text
from gicore.results import Results, read_rows
from gigan_local.inference import DEFAULT_MODEL


@pytest.mark.slow  # the shipped model at 256², onnxruntime and torch on the CPU (~8 s)
def test_inference_rows_and_the_warm_started_torch_generator_match_onnxruntime(tmp_path: Path) -> None:
    cfg = InferenceConfig(models=(SHIPPED_FP32, DEFAULT_MODEL), threads=(1,), torch_device="cpu", repeats=3, warmup=1)
    res = Results("inference", tmp_path, 0)
    measure(cfg, res)
    csv_path = res.write()
    rows = read_rows(csv_path)

    def get(system: str, metric: str, stat: str = "value", **config) -> float:
        [v] = [
            r["value"]
            for r in rows
            if (r["system"], r["metric"], r["stat"]) == (system, metric, stat) and r["config"].items() >= config.items()
        ]
        return v

    # the reference configuration against itself: bit-identical (one session, one input)
    assert get("onnxruntime", "max_abs_error", precision="fp32") == 0.0
    # the fp16 file: its weights rounded to half precision, a small but non-zero difference
    assert 0 < get("onnxruntime", "max_abs_error", precision="fp16") < 0.05
    # torch on the weights read back from the ONNX file computes the same network (measured 6.9e-7)
    for copies in ("device", "host"):
        assert get("torch", "max_abs_error", precision="fp32", copies=copies) < 1e-4
        assert get("torch", "inference", "median", copies=copies) > 0
        assert get("torch", "inference", "n", copies=copies) == 3
    assert not [r for r in rows if r["system"] == "torch" and r["config"]["precision"] != "fp32"]  # CPU: fp32 only
    text = table_text(TABLE, rows, 2)
    medians = [float(line.split(" | ")[5]) for line in text.splitlines()[2:]]
    assert len(medians) == 4 and medians == sorted(medians)
    written = write_files("inference", BENCH.parts, rows, tmp_path)
    assert [p.name for p in written] == ["inference.md", "inference.png", "inference.svg"]
    assert ">torch fp32 cpu copies host</text>" in (tmp_path / "inference.svg").read_text()  # a declared series


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"backends": ("onnxruntime", "tensorrt")}, "--backends 'tensorrt' is not one of"),
        ({"precisions": ("fp8",)}, "--precisions 'fp8' is not one of"),
        ({"torch_device": "tpu"}, "--torch-device 'tpu' is not auto, cpu or cuda"),
        ({"models": (Path("/nonexistent/model.onnx"),)}, "is not a file"),
    ],
)
def test_config_is_checked(changes, message) -> None:
    with pytest.raises(UserError, match=message):
        InferenceConfig(**changes).check()


def test_models_of_different_inputs_are_refused(tmp_path: Path) -> None:
    import json
    import shutil

    shipped = DEFAULT_MODEL
    other = tmp_path / "model_fp16.onnx"
    shutil.copy(shipped, other)
    doc = json.loads((shipped.parent / "model.json").read_text())
    (tmp_path / "model.json").write_text(json.dumps(doc | {"resolution": 128}))
    with pytest.raises(UserError, match="take different inputs"):
        InferenceConfig(models=(SHIPPED_FP32, other)).check()
