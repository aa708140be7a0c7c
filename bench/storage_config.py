"""`bench storage`'s configuration (:class:`StorageConfig`) and the constants its measurement and tables share:
the paper's Table 2, its accounting (an uncompressed RGB8 map per frame, :data:`RAW_CODEC`), the payloads of
both compositions."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from baseline_cloudbaking.codecs import CODEC_NAMES, CodecName
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL
from baseline_cloudbaking.viewpoints import Tolerance
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.options import FRAMES
from gicore.path_file import read_sessions
from gicore.scene import builtin_scenes, load_scene
from gigan_local.inference import DEFAULT_MODEL

COMPOSITIONS = {"blend": ("gi", "depth"), "residual": ("gi", "di", "depth")}
#: The paper's Table 2 (GB): GI tree per scene after its fly-through, and the one model for every scene.
PAPER_TABLE2_GB = {"lung": 1.15, "digestive": 2.38, "vessels": 3.36, "model": 0.2}
#: The paper's accounting: one uncompressed RGB8 GI map per frame, i.e. a tree that never reuses a map (Δ 0).
RAW_CODEC = "rgb8"
PAPER_TOLERANCE = Tolerance(0.0, 0.0)


@dataclass(frozen=True)
class StorageConfig:
    """What one storage run measures (see the module docstring for measured vs extrapolated)."""

    scenes: tuple[str, ...] = option_groups.scenes(tuple(builtin_scenes()), note="Table 2's rows")
    #: Frames of each scene's fly-through (paper: 1500).
    frames: int = 1500
    #: Square map resolutions.
    resolutions: tuple[int, ...] = (256, 512)
    #: GI-map codecs; the first one is the tolerance knob's.
    codecs: tuple[CodecName, ...] = CODEC_NAMES
    spp: int = option_groups.spp(note="of the rendered maps, then OIDN")
    #: Maps rendered per scene and resolution to measure bytes per entry (all entries if fewer).
    samples: int = 12
    #: Δp: eye distance within which a stored map serves a frame, scene units.
    tolerance_position: float = field(default=Tolerance.position, metadata={"min": 0.0})
    #: Δθ: view-direction angle within which a stored map serves a frame, degrees.
    tolerance_angle_deg: float = field(default=Tolerance.angle_deg, metadata={"min": 0.0, "max": 180.0})
    #: Light-cell side for scenes whose light moves, scene units.
    light_cell: float = DEFAULT_LIGHT_CELL
    #: Tolerance knob: the Δp of each setting (paired with knob_angles_deg).
    knob_positions: tuple[float, ...] = field(default=(0.0, 0.02, 0.05, 0.1, 0.2), metadata={"min": 0.0})
    #: Tolerance knob: the Δθ (degrees) of each setting.
    knob_angles_deg: tuple[float, ...] = field(default=(0.0, 1.0, 2.0, 5.0, 10.0), metadata={"min": 0.0, "max": 180.0})
    #: σ of the second pass's eye perturbation per axis, scene units.
    perturb_position: float = 0.02
    #: σ of the second pass's view perturbation, degrees.
    perturb_angle_deg: float = 1.0
    #: Hits per knob setting whose warped map is scored against a render at the perturbed camera.
    warp_samples: int = 6
    #: Folder of the shipped GIGAN model (model_fp32.onnx, model_fp16.onnx, model.json): the client storage.
    model_dir: Path = DEFAULT_MODEL.parent
    #: Growth law: user sessions the GI tree sees per scene (gicore.sessions).
    sessions: int = field(default=200, metadata={"min": 1, "max": 10_000})
    #: Growth law: how many users the sessions come from (in turn), one curve per value.
    users: tuple[int, ...] = field(default=(1, 8), metadata={"min": 1, "max": 10_000})
    #: Growth law: frames per session.
    session_frames: int = field(default=1500, metadata=FRAMES)
    #: Growth law: a folder of recorded sessions flown in place of the seeded ones: every *.json path file in it
    #: (gigan-path/1, in name order; each scene's are those naming it), one curve, recorded as 1 user.
    sessions_from: Path | None = field(default=None, metadata={"conflicts": ("sessions", "users", "session_frames")})
    #: Growth law: maps baked per scene and resolution at entries of the session tree to measure bytes per entry.
    growth_samples: int = field(default=4, metadata={"min": 1, "max": 256})
    #: Growth law: saturated from the session after which no session adds more entries than this fraction of its
    #: frames.
    saturation_rate: float = field(default=0.01, metadata={"min": 0.0, "max": 1.0})
    #: Growth law: viewpoints drawn uniformly from the navigable space to estimate the tree's saturation level.
    capacity_samples: int = field(default=50_000, metadata={"min": 10, "max": 1_000_000})
    #: Resolution of the paper-accounting row (one uncompressed RGB8 map per frame); one of --resolutions.
    paper_resolution: int = 512
    #: Folder caching the growth law's baked maps across runs (key: scene spec, camera, light, spp, seed).
    map_cache: Path = Path(".cache/storage_maps")

    @classmethod
    def quick(cls) -> StorageConfig:
        return cls(
            scenes=("lung_plane", "vessels_plane"),
            frames=300,
            spp=16,
            samples=3,
            knob_positions=(0.02, 0.05, 0.2),
            knob_angles_deg=(1.0, 2.0, 10.0),
            warp_samples=2,
            sessions=6,
            users=(2,),
            session_frames=300,
            growth_samples=1,
            capacity_samples=2000,
        )

    def check(self) -> None:
        if self.map_cache.exists() and not self.map_cache.is_dir():
            raise UserError(f"--map-cache {self.map_cache} is a file", "give a folder path")
        if self.paper_resolution not in self.resolutions:
            raise UserError(
                f"--paper-resolution {self.paper_resolution} is not one of --resolutions "
                f"{','.join(map(str, self.resolutions))}",
                "add it to --resolutions (the paper's accounting is at 512)",
            )
        if len(self.knob_positions) != len(self.knob_angles_deg):
            raise UserError(
                f"--knob-positions has {len(self.knob_positions)} values but "
                f"--knob-angles-deg {len(self.knob_angles_deg)}",
                "give one angle per position (they are paired)",
            )
        missing = [p for p in ("model_fp32.onnx", "model_fp16.onnx") if not (self.model_dir / p).is_file()]
        if missing:
            raise UserError(
                f"--model-dir {self.model_dir} lacks {', '.join(missing)}",
                "give the folder of an exported GIGAN model (gigan-export)",
            )
        if self.sessions_from is not None:  # every recorded session checked before anything is measured
            read_sessions(self.sessions_from, [load_scene(s) for s in self.scenes])

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_position, self.tolerance_angle_deg)
