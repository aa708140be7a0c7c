"""GI-map codecs, depth coding and the payload protocol of cloud baking (docs/architecture.md, Codecs)."""

from __future__ import annotations

import numpy as np
import pytest

from baseline_cloudbaking.bake import BakedMap, bake_map, encode_map
from baseline_cloudbaking.codecs import CODEC_NAMES, CODECS, DEPTH_CODEC, CodecError, get_codec, measure
from baseline_cloudbaking.protocol import MAGIC, PayloadError, decode_payload, pack, unpack, with_header
from gicore.camera import Camera
from gicore.tonemap import inverse_tonemap
from tests.helpers.cloud import RES, SPP


@pytest.fixture(scope="module")
def baked(make_spec) -> BakedMap:
    """A real map: sphere in a Cornell box (coloured indirect light), path traced + OIDN, with DI."""
    from gicore.render import Renderer

    spec = make_spec(
        environment="cornell_box",
        light={"position": [0.0, 2.2, 0.3], "intensity": 8.0},
        camera={"radius": 2.0, "height": 1.0},
    )
    camera = Camera((1.2, 1.1, 1.5), (0.0, 0.5, 0.0), fov=90.0, width=RES, height=RES)
    return bake_map(Renderer(spec, RES), camera, (0.0, 2.2, 0.3), spp=SPP, seed=3, di=True)


def test_the_map_is_denoised_gi_with_di_and_depth(baked: BakedMap) -> None:
    assert baked.gi.shape == baked.di.shape == (RES, RES, 3) and baked.depth.shape == (RES, RES)
    assert baked.gi.min() >= 0.0 and np.isfinite(baked.gi).all()
    hit = baked.depth > 0
    assert 0.5 < hit.mean() <= 1.0  # the Cornell box fills most of a 90° view
    # GI carries the indirect light DI lacks: on average brighter, never dimmer by much anywhere
    assert baked.gi[hit].mean() > 1.2 * baked.di[hit].mean()


@pytest.mark.parametrize("name", CODEC_NAMES)
def test_round_trip_within_stated_error(name: str, baked: BakedMap) -> None:
    codec = get_codec(name)
    for image in (baked.gi, baked.di):
        report, data, decoded = measure(codec, image)
        assert decoded.shape == image.shape and decoded.dtype == np.float32 and np.isfinite(decoded).all()
        assert report.bytes == len(data) > 0 and report.encode_ms > 0 and report.decode_ms > 0
        assert report.rmse <= codec.max_rmse, report
        assert report.ssim >= (0.999 if codec.lossless else 0.93), report
        if codec.lossless:
            assert np.array_equal(decoded, codec.quantize(image))
        else:
            assert not np.array_equal(decoded, codec.quantize(image))  # really lossy: the test means something


@pytest.mark.parametrize("name", [n for n in CODEC_NAMES if CODECS[n].lossless])
def test_lossless_codecs_are_exact_on_hdr_extremes(name: str) -> None:
    rng = np.random.default_rng(0)
    image = (rng.random((24, 40, 3)) ** 6 * 1e3).astype(np.float32)  # 0 to 1000, wide dynamic range
    image[0, :5] = 0.0
    codec = CODECS[name]
    decoded = codec.decode(codec.encode(image))
    assert np.array_equal(decoded, codec.quantize(image))


def test_eight_bit_codecs_saturate_instead_of_exploding() -> None:
    image = np.full((8, 8, 3), 1e4, dtype=np.float32)
    top = float(inverse_tonemap(np.float32(254.5 / 255.0)))
    for name in ("jpeg", "webp", "avif", "png"):
        decoded = CODECS[name].decode(CODECS[name].encode(image))
        assert np.allclose(decoded, top, rtol=0.05), name  # ~230: the top 8-bit bin, not 4e4
    assert CODECS["exr-half"].decode(CODECS["exr-half"].encode(image * 100)).max() == np.float16(
        65504
    )  # clipped, not inf


@pytest.mark.parametrize("name", CODEC_NAMES)
def test_corrupt_bytes_are_a_codec_error(name: str, baked: BakedMap) -> None:
    codec = CODECS[name]
    data = codec.encode(baked.gi)
    other = CODECS["png" if name != "png" else "jpeg"].encode(baked.gi)
    for bad in (b"", b"garbage" * 20, data[: len(data) // 3], other):
        with pytest.raises(CodecError, match=name):
            codec.decode(bad)


def test_bad_maps_are_refused() -> None:
    with pytest.raises(ValueError, match="HxWx3"):
        CODECS["jpeg"].encode(np.zeros((8, 8), dtype=np.float32))
    with pytest.raises(ValueError, match="NaN or Inf"):
        CODECS["zstd-f16"].encode(np.full((8, 8, 3), np.nan, dtype=np.float32))
    with pytest.raises(ValueError, match="known codecs: jpeg, webp, avif, png, exr-half, zstd-f16"):
        get_codec("gif")
    for not_a_name in (123, None, ["jpeg"]):  # what a payload header may hold
        with pytest.raises(ValueError, match="a codec is named by a string"):
            get_codec(not_a_name)


def test_codec_quality_is_the_knob_it_claims() -> None:
    rng = np.random.default_rng(0)
    image = np.clip(rng.normal(0.5, 0.2, (64, 64, 3)), 0, None).astype(np.float32)
    sizes = {q: len(get_codec(f"jpeg:{q}").encode(image)) for q in (20, 60, 95)}
    assert sizes[20] < sizes[60] < sizes[95]
    assert get_codec("jpeg:60").name == "jpeg:60" and dict(get_codec("jpeg:60").options)["quality"] == 60
    assert get_codec("png") is CODECS["png"]
    for bad in ("jpeg:101", "jpeg:0", "jpeg:", "png:50"):
        with pytest.raises(ValueError, match="a quality 1 to 100 is known for jpeg, webp, avif only"):
            get_codec(bad)


# -- depth ------------------------------------------------------------------------------------------
def test_depth_loss_is_far_below_the_warp_depth_test(baked: BakedMap) -> None:
    from gigan_local.warp import DEPTH_REL_TOL

    depth = baked.depth
    data = DEPTH_CODEC.encode(depth)
    decoded = DEPTH_CODEC.decode(data)
    assert np.array_equal(decoded, DEPTH_CODEC.quantize(depth))  # exact after the float16 rounding
    assert np.array_equal(decoded == 0, depth == 0)  # background stays background
    hit = depth > 0
    rel = np.abs(decoded[hit] - depth[hit]) / depth[hit]
    assert rel.max() <= DEPTH_CODEC.max_rel_error <= DEPTH_REL_TOL / 40
    assert len(data) < depth.nbytes / 3  # and it is small: the point of rounding


def test_depth_rounding_moves_reprojected_texels_by_under_a_tenth_of_a_pixel(baked: BakedMap) -> None:
    """Unproject every texel with exact and with decoded depth, project both into a camera that moved."""
    src = baked.camera
    target = Camera((0.9, 1.3, 1.8), (0.1, 0.5, 0.0), fov=60.0, width=RES, height=RES)

    def pixels(depth: np.ndarray) -> np.ndarray:
        rows, cols = np.nonzero(baked.depth > 0)
        d = depth[rows, cols].astype(np.float64)
        p = src.proj()
        x_ndc, y_ndc = 2.0 * (cols + 0.5) / RES - 1.0, 1.0 - 2.0 * (rows + 0.5) / RES
        eye = np.stack([x_ndc * d / p[0, 0], y_ndc * d / p[1, 1], -d, np.ones_like(d)])
        world = (np.linalg.inv(src.view()) @ eye)[:3].T
        return target.project_pixels(world)[0]

    exact, rounded = pixels(baked.depth), pixels(DEPTH_CODEC.decode(DEPTH_CODEC.encode(baked.depth)))
    assert np.max(np.linalg.norm(exact - rounded, axis=1)) < 0.1


def test_bad_depth_is_refused() -> None:
    for bad in (
        np.full((4, 4), np.nan, np.float32),
        np.full((4, 4), -1.0, np.float32),
        np.zeros((4, 4)),
        np.zeros((4, 4, 1), np.float32),
    ):
        with pytest.raises(ValueError, match="depth must"):
            DEPTH_CODEC.encode(bad)
    with pytest.raises(CodecError, match="header"):
        DEPTH_CODEC.decode(b"\x01")


# -- payload protocol -------------------------------------------------------------------------------
def test_payload_round_trip_carries_map_depth_and_camera(baked: BakedMap) -> None:
    payload = encode_map(baked, "demo", "webp", SPP, light=(0.0, 2.2, 0.3))
    assert payload.startswith(MAGIC)
    decoded = decode_payload(payload)
    codec = CODECS["webp"]
    assert np.array_equal(decoded.gi, codec.decode(codec.encode(baked.gi)))
    assert np.array_equal(decoded.di, codec.decode(codec.encode(baked.di)))
    assert np.array_equal(decoded.depth, DEPTH_CODEC.quantize(baked.depth))
    assert decoded.camera == baked.camera
    assert np.allclose(decoded.view, baked.camera.view()) and np.allclose(decoded.proj, baked.camera.proj())
    assert decoded.header["light"] == [0.0, 2.2, 0.3] and decoded.hit is None
    assert set(decoded.header["bake_ms"]) == {"render", "denoise", "encode"}
    # a served copy: extra header fields, the DI section dropped, the other sections byte-identical
    served = with_header(payload, {"hit": True, "timings_ms": {"lookup": 0.1}}, drop=("di",))
    header, sections = unpack(served)
    assert header["hit"] is True and [s["name"] for s in header["sections"]] == ["gi", "depth"]
    assert bytes(sections["gi"]) == bytes(unpack(payload)[1]["gi"])
    again = decode_payload(served)
    assert again.di is None and again.hit is True and again.timings_ms == {"lookup": 0.1}
    # nothing dropped: the extra fields are spliced into the header's text, the result as if encoded again
    extra = {"hit": True, "distance": {"position": 0.01, "angle_deg": 0.5}, "timings_ms": {"total": 1.5}}
    spliced = with_header(payload, extra)
    header, sections = unpack(spliced)
    assert header == unpack(payload)[0] | extra and list(sections) == ["gi", "di", "depth"]
    assert all(bytes(sections[n]) == bytes(unpack(payload)[1][n]) for n in sections)
    assert decode_payload(spliced).hit is True
    # a key the header has already is replaced, not repeated
    assert unpack(with_header(spliced, {"hit": False}))[0]["hit"] is False
    assert spliced.count(b'"hit"') == 1 and with_header(spliced, {"hit": False}).count(b'"hit"') == 1


def test_static_light_payload_names_no_light(baked: BakedMap) -> None:
    assert "light" not in decode_payload(encode_map(baked, "demo", "jpeg", SPP, light=None)).header


def test_malformed_payloads_are_payload_errors(baked: BakedMap) -> None:
    good = encode_map(baked, "demo", "jpeg", SPP, light=None)
    header_len = int.from_bytes(good[4:8], "little")
    cases = {
        "does not start": b"JUNK" + good[4:],
        "does not fit": good[:4] + (10**6).to_bytes(4, "little") + good[8:],
        "header is not valid": good[:8] + b"{" * header_len + good[8 + header_len :],
        "runs past the end": good[:-10],
        "follow the last section": good + b"extra",
    }
    for message, data in cases.items():
        with pytest.raises(PayloadError, match=message):
            decode_payload(data)
    with pytest.raises(PayloadError, match="lacks the gi or depth"):
        decode_payload(pack({"codec": "jpeg"}, {"gi": b"x"}))


def test_8bit_decode_by_table_equals_the_inverse_tone_map_bit_for_bit() -> None:
    """The 8-bit codecs look each byte's linear value up in a table: the same float32 bits as the formula, for every
    byte, in any position of an array of any shape (a vectorised kernel's lanes and tail alike)."""
    from gicore.tonemap import inverse_u8, linear_of_display

    rng = np.random.default_rng(4)
    for shape in ((256,), (257, 131, 3), (1, 1, 3)):
        q = rng.integers(0, 256, shape, dtype=np.uint8)
        assert np.array_equal(linear_of_display(q).view(np.uint32), inverse_u8(q).view(np.uint32))
    every = np.arange(256, dtype=np.uint8)
    assert np.array_equal(linear_of_display(every).view(np.uint32), inverse_u8(every).view(np.uint32))
    assert inverse_u8(every)[0] == 0.0 and np.all(np.diff(inverse_u8(every)) > 0)  # monotone, finite
    assert np.isfinite(inverse_u8(every)).all()


def test_8bit_codecs_hand_their_display_values_over_as_they_decode_them() -> None:
    """``decode_display`` is ``decode`` before the inverse tone map: a GL warp that decodes on the GPU starts from
    the same bytes the host decode turns into radiance."""
    from baseline_cloudbaking.codecs import get_codec
    from gicore.tonemap import linear_of_display

    image = np.random.default_rng(5).uniform(0.0, 4.0, (16, 24, 3)).astype(np.float32)
    for name in ("jpeg", "png", "webp"):
        codec = get_codec(name)
        data = codec.encode(image)
        display = codec.decode_display(data)
        assert display.dtype == np.uint8 and display.shape == image.shape
        assert np.array_equal(linear_of_display(display), codec.decode(data))
