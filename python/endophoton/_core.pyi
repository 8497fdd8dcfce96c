"""Type stubs of endophoton._core, the engine's pybind11 binding (native/bindings/, docs/design.md,
"Native binding"). The package calls it; users call the package. Lengths in scene units unless a
name says otherwise; wavelengths in nm; mua, mus in cm^-1.

tests/python/test_core_stubs.py holds these stubs to the module: every public name of _core (and of
its classes) has a stub here, and every stub names something _core has.
"""

from typing import Any, Callable, Sequence

import numpy as np
import numpy.typing as npt

__version__: str
MAX_REGIONS: int
MAX_PACKET_REQUEST: int
DEFAULT_TARGET_MAX_PACKETS: int
DEFAULT_CACHE_STORE_BYTES: int
MIN_WAVELENGTH_NM: float
MAX_WAVELENGTH_NM: float
BALANCE_TALLIES: tuple[str, ...]

class InvalidArgument(ValueError):
    """The engine's error for bad input: the message names the field and the value."""

class Scene:
    """The engine's scene: closed triangle meshes (regions) in an ambient medium."""

    def __init__(self, unit_cm: float, ambient_n: float = 1.0) -> None: ...
    def add_region(
        self,
        name: str,
        vertices: npt.NDArray[np.float32],
        triangles: npt.NDArray[np.uint32],
        mua: float,
        mus: float,
        g: float,
        n: float,
        priority: int = 0,
        mua_table: tuple[Sequence[float], Sequence[float]] | None = None,
        mus_table: tuple[Sequence[float], Sequence[float]] | None = None,
    ) -> int: ...
    def add_fluorophore(
        self, name: str, excitation_nm: Sequence[float], emission_nm: Sequence[float], values: Sequence[float]
    ) -> int: ...
    def set_region_fluorophores(self, region: int, fluorophores: Sequence[tuple[int, float, float]]) -> None: ...
    def commit(self) -> None: ...
    @property
    def cache_store_bytes(self) -> int: ...
    @property
    def cache_store_cap_bytes(self) -> int: ...
    @cache_store_cap_bytes.setter
    def cache_store_cap_bytes(self, value: int) -> None: ...

class Source:
    """The lights (dicts: position, direction, radius, half_angle in radians, optional spectrum) and the
    optional rig head ``body``."""

    def __init__(self, lights: Sequence[dict[str, Any]], body: dict[str, Any] | None = None) -> None: ...

class CancelToken:
    """A flag any thread may set; a run polls it."""

    def __init__(self) -> None: ...
    def cancel(self) -> None: ...
    @property
    def cancelled(self) -> bool: ...

class CameraView:
    """The camera tally's request (native/camera_tally.h); built by endophoton.view.nee."""

    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def batches(self) -> int: ...
    @property
    def channels(self) -> int: ...
    @property
    def packets(self) -> int: ...
    # False: every event's path is solved before its depth roulette (the tests' reference); default True.
    depth_bound: bool
    # The look-back next event (docs/render.md): its switch and proposal, set at construction.
    @property
    def look_back(self) -> bool: ...
    @property
    def look_back_alpha(self) -> float: ...
    @property
    def look_back_g(self) -> float: ...
    # False drops the look-back's weight ratio (a deliberately biased image, for the tests); default True.
    look_back_ratio: bool
    def __init__(self, **options: Any) -> None: ...

class RunConfig:
    """Options of one run (native/run_config.h), one attribute per field; RunConfig(**options)."""

    photons: int
    store: int
    fluorescent_only: bool
    record_escapes: bool
    max_records: int
    seed: int
    threads: int
    roulette_threshold: float
    roulette_chance: float
    max_steps: int
    max_path_cm: float
    force_spectral: bool
    grid_voxel_size: float
    grid_per_fluorophore: bool
    grid_absorbed: bool
    grid_fluorescent_light: bool
    grid_emission: bool
    grid_path: str
    grid_max_tree_bytes: int
    target_rel_error: float
    time_budget_s: float
    max_photons: int
    unit_size: int
    batches: int
    safe_distance: bool
    lanes: bool
    lumen: bool
    stats: bool
    camera_view: CameraView | None
    test_cancel_after_units: int
    test_cancel_at_packet: int
    test_fail_thread: int
    fluorescence_rule: str
    target_tally: str
    def __init__(self, **options: Any) -> None: ...

def run(
    scene: Scene,
    source: Source,
    config: RunConfig,
    progress: Callable[[int, int], bool | None] | None = None,
    cancel: CancelToken | None = None,
) -> dict[str, Any]:
    """Trace a run (GIL released); its estimates, records and counters as a dict."""

def check_run(scene: Scene, source: Source, config: RunConfig) -> list[str]:
    """run()'s validation alone, without tracing; the warnings the run would start with."""

def check_mesh(owner: str, vertices: npt.NDArray[np.float32], triangles: npt.NDArray[np.uint32]) -> dict[str, Any]:
    """The closed-mesh rule: signed_volume (scene units^3), bbox_min, bbox_max, welded_vertices."""

def check_spectrum(name: str, wavelength_nm: npt.ArrayLike, values: npt.ArrayLike) -> None:
    """The spectrum rules (native/spectrum_check.h); ValueError naming the field, index and value."""

def check_eem(name: str, excitation_nm: npt.ArrayLike, emission_nm: npt.ArrayLike, values: npt.ArrayLike) -> None:
    """The excitation-emission matrix rules (native/spectrum_check.h); values of shape (n_ex, n_em)."""

def det_sin(x: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """sin x (radians), elementwise, SLEEF (native/det_math.h): the same bits on every x86-64 machine."""

def det_cos(x: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """cos x (radians), elementwise, SLEEF: the same bits on every x86-64 machine."""

def det_tan(x: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """tan x (radians), elementwise, SLEEF: the same bits on every x86-64 machine."""

def det_atan(x: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """atan x (radians, in (-pi/2, pi/2)), elementwise, SLEEF: the same bits on every x86-64 machine."""

def det_exp(x: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """e^x, elementwise, SLEEF: the same bits on every x86-64 machine."""

def det_log(x: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """ln x, elementwise, SLEEF: the same bits on every x86-64 machine."""

def det_pow(x: npt.ArrayLike, y: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """x ** y, elementwise over two arrays of one shape, SLEEF: the same bits on every x86-64 machine."""

def first_surfaces(
    scene: Scene,
    origins: npt.NDArray[np.float64],
    directions: npt.NDArray[np.float64],
    tfar: npt.ArrayLike | None = None,
    tnear: float = 0.0,
    threads: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, region, triangle, normal) of the first entry into tissue along each ray (region -1: none,
    -2: the ray starts inside a region)."""

class ExitIndex:
    """The records of each region that ``keep`` marks, one kd-tree per region (native/exit_gather.h): the
    exitance estimate's searches and sums. Keeps the position and region arrays alive."""

    def __init__(
        self,
        rec_pos: npt.NDArray[np.float64],
        rec_region: npt.NDArray[np.int32],
        keep: npt.NDArray[np.uint8],
        regions: int,
    ) -> None: ...
    def kth_distance(
        self,
        use: npt.NDArray[np.uint8],
        px: npt.NDArray[np.float64],
        preg: npt.NDArray[np.int32],
        k: int,
        threads: int = 0,
        cancel: CancelToken | None = None,
    ) -> np.ndarray | None:
        """Per pixel, the distance to the k-th nearest marked record of its region (the farthest where fewer
        than k, inf where fewer than 2); None once cancelled."""
    def gather(
        self,
        rec_batch: npt.NDArray[np.int32],
        rec_band: npt.NDArray[np.int32],
        rec_sbin: npt.NDArray[np.int32],
        rec_cmf: npt.NDArray[np.float64],
        rec_cam: npt.NDArray[np.float64],
        energy: npt.NDArray[np.float64],
        coef: npt.NDArray[np.float64],
        px: npt.NDArray[np.float64],
        preg: npt.NDArray[np.int32],
        mu_rows: npt.NDArray[np.float64],
        radius: npt.NDArray[np.float64],
        grown: npt.NDArray[np.uint8],
        scale: npt.NDArray[np.float64],
        image_index: npt.NDArray[np.int64],
        image_size: int,
        spectrum_bins: int,
        threads: int = 0,
        cancel: CancelToken | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """(W, W_half, XYZ, CAM, SPEC): the exitance estimate's sums; None once cancelled."""

def unit_plan(scene: Scene, source: Source, options: RunConfig) -> tuple[int, int]:
    """(unit_size, n_units_max) of a request; validates it as run() does."""

def trace_units(scene: Scene, source: Source, options: RunConfig, first_unit: int, count: int) -> bytes:
    """Units first_unit .. first_unit + count - 1 traced (GIL released), as bytes for UnitReducer.add."""

class UnitReducer:
    """Merges trace_units bytes in unit order through the engine's own reducer."""

    def __init__(self, scene: Scene, source: Source, options: RunConfig) -> None: ...
    def add(self, batch: bytes) -> tuple[bool, int]: ...
    def finish(self, threads: int = 0) -> dict[str, Any]: ...
    @property
    def stopped(self) -> bool: ...
    @property
    def merged_units(self) -> int: ...
    @property
    def records(self) -> int: ...
