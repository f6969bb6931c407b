"""Type stubs of the `needle` module (src/lib.rs). Lengths in mm, forces in N, times in ms."""

import os
from typing import Any, Callable, Mapping, Optional, Union

import numpy as np
import numpy.typing as npt

__version__: str
BUILTIN_SCENES: list[str]

Overrides = Mapping[str, Any]
SceneLike = Union["Scene", str, os.PathLike[str]]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

class SceneError(ValueError):
    file: str
    field: str
    reason: str

class SetupError(ValueError): ...
class SimulationError(RuntimeError): ...

class Scene:
    def __init__(self, scene: SceneLike, overrides: Optional[Overrides] = None) -> None: ...
    @staticmethod
    def from_toml(text: str, name: str = "<string>") -> "Scene": ...
    def with_overrides(self, overrides: Overrides) -> "Scene": ...
    @property
    def name(self) -> str: ...
    @property
    def planned_steps(self) -> int: ...
    def to_toml(self) -> str: ...

class StepReport:
    step: int
    c: float
    tip: F64
    target: F64
    error: float
    depth: float
    punctured: bool
    punctured_now: bool
    inside: bool
    rows: int
    sliding_points: int
    contact_force: float
    residual: float
    gs_iterations: int
    joints: F64
    times: dict[str, float]
    def to_dict(self) -> dict[str, Any]: ...

class Simulation:
    def __init__(self, scene: SceneLike, overrides: Optional[Overrides] = None) -> None: ...
    def step(self) -> StepReport: ...
    name: str
    planned_steps: int
    steps: int
    dt: float
    c: float
    tip: F64
    target: F64
    error: float
    depth: float
    punctured: bool
    in_contact: bool
    joints: F64
    joint_count: int
    needle_positions: F64
    gel_positions: F64
    gel_rest_positions: F64
    gel_tets: I64
    gel_surface: I64
    entry_point: F64
    clearances: F64

class RunResult:
    summary: dict[str, Any]
    outcome: str
    steps: I64
    c: F64
    errors: F64
    depths: F64
    punctured: npt.NDArray[np.bool_]
    inside: npt.NDArray[np.bool_]
    tips: F64
    targets: F64
    joints: F64
    stage_times: dict[str, F64]
    error_by_depth: F64
    reports: list[StepReport]
    def __len__(self) -> int: ...

def run(
    scene: SceneLike,
    overrides: Optional[Overrides] = None,
    *,
    callback: Optional[Callable[[StepReport], object]] = None,
    steps: Optional[int] = None,
    controller: str = "inverse",
    out: Optional[Union[str, os.PathLike[str]]] = None,
    vtk_every: Optional[int] = None,
) -> RunResult: ...
