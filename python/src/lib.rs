//! The `needle` Python module: scenes, a simulation stepped from Python, and whole runs through
//! the same host loop as `needle run`.
//!
//! ```python
//! import needle
//! sim = needle.Simulation("simple", overrides={"gel.box.nodes": 600})
//! r = sim.step()                         # a StepReport: r.tip, r.error, r.times, ...
//! result = needle.run("simple", callback=lambda r: None)
//! result.summary["e_mean_mm"], result.errors, result.stage_times["fm"]
//! ```
//!
//! - [`Scene`]: an embedded scene (`"simple"`, `"complex"`) or a TOML file, with overrides
//!   given as a dict of dotted field → Python value (turned into the TOML value `--set` takes).
//! - [`Simulation`]: the world, the step pipeline and the core in this process, stepped one step
//!   at a time as `host/examples/run_scene.rs` does; positions as NumPy arrays.
//! - [`run`]: `needle_host::run`'s loop (`Setup::build`, the core in process, `run_setup`: the
//!   watchdog, the settling steps, the outcome), as the CLI's `needle run` calls it, with a
//!   Python callback per step. The summary is `needle run --json`'s, as a dict.
//!
//! Errors raise `needle.SceneError` (a `ValueError`: the file, the field and the reason),
//! `needle.SetupError` (a `ValueError`: the scene cannot be set up) or
//! `needle.SimulationError` (a `RuntimeError`: a failed step, an output that cannot be written),
//! each with the host's message.

use nalgebra::Vector3;
use needle_bridge::InProcess;
use needle_host::error::chain;
use needle_host::run::{ControllerKind, RunError, RunOptions};
use needle_host::scene::{MAX_STEPS, Scene as HostScene, SceneError as HostSceneError};
use needle_host::setup::{Plan, Setup, WithSetup, with_setup};
use needle_host::step::{Pipeline, ROWS, StageTimes, StepParams, StepReport as HostReport};
use needle_host::world::World;
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use std::any::Any;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::Mutex;

create_exception!(
    needle,
    SceneError,
    PyValueError,
    "A scene that cannot be loaded: a missing file, a syntax error, an unknown field, a bad \
     value or override. Attributes: `file`, `field` (dotted path, empty for a syntax error), \
     `reason`."
);
create_exception!(
    needle,
    SetupError,
    PyValueError,
    "A scene that cannot be set up: a path outside the gel, an obstacle on the path, an \
     unreachable start pose, an invalid mesh (the message names the field)."
);
create_exception!(
    needle,
    SimulationError,
    PyRuntimeError,
    "A step that failed (the simulation cannot go on), or an output that cannot be written."
);

fn scene_error(py: Python<'_>, e: &HostSceneError) -> PyErr {
    let err = SceneError::new_err(e.to_string());
    let value = err.value(py);
    // Setting attributes on a fresh exception instance does not fail.
    let _ = value.setattr("file", &e.file);
    let _ = value.setattr("field", &e.field);
    let _ = value.setattr("reason", &e.reason);
    err
}

fn run_error(e: &RunError) -> PyErr {
    match e {
        RunError::Setup(s) => SetupError::new_err(chain(s)),
        other => SimulationError::new_err(chain(other)),
    }
}

/// A Python value as the TOML value text an override takes (`600`, `0.001`, `"paper"`,
/// `[1.0, 2.0]`, `{ x = 1 }`).
fn toml_value(field: &str, v: &Bound<'_, PyAny>) -> PyResult<toml::Value> {
    if v.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(v.extract()?));
    }
    if v.is_instance_of::<PyInt>() {
        let n: i64 = v.extract().map_err(|_| {
            PyValueError::new_err(format!("override `{field}`: {v} does not fit in 64 bits"))
        })?;
        return Ok(toml::Value::Integer(n));
    }
    if v.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(v.extract()?));
    }
    if v.is_instance_of::<PyString>() {
        return Ok(toml::Value::String(v.extract()?));
    }
    if v.is_instance_of::<PyList>() || v.is_instance_of::<PyTuple>() {
        return v
            .try_iter()?
            .map(|item| toml_value(field, &item?))
            .collect::<PyResult<Vec<_>>>()
            .map(toml::Value::Array);
    }
    if let Ok(d) = v.cast::<PyDict>() {
        let mut table = toml::Table::new();
        for (k, item) in d.iter() {
            let key: String = k.extract()?;
            let value = toml_value(&format!("{field}.{key}"), &item)?;
            table.insert(key, value);
        }
        return Ok(toml::Value::Table(table));
    }
    // NumPy scalars and other numbers.
    if let Ok(x) = v.extract::<f64>() {
        return Ok(toml::Value::Float(x));
    }
    Err(PyTypeError::new_err(format!(
        "override `{field}`: a {} is not a scene value (bool, int, float, str, list or dict)",
        v.get_type().name()?
    )))
}

/// `overrides` (a dict of dotted field → value) as the host's `(field, TOML text)` pairs.
fn override_pairs(overrides: Option<&Bound<'_, PyDict>>) -> PyResult<Vec<(String, String)>> {
    let Some(d) = overrides else {
        return Ok(Vec::new());
    };
    d.iter()
        .map(|(k, v)| {
            let field: String = k
                .extract()
                .map_err(|_| PyTypeError::new_err(format!("override field {k}: expected a str")))?;
            let text = toml_value(&field, &v)?.to_string();
            Ok((field, text))
        })
        .collect()
}

/// The scene `arg` names: a [`Scene`], a path (`str` or `os.PathLike`: a file), or the name of
/// an embedded scene, with `overrides` applied.
fn load_scene(
    py: Python<'_>,
    arg: &Bound<'_, PyAny>,
    overrides: Option<&Bound<'_, PyDict>>,
) -> PyResult<HostScene> {
    let scene = if let Ok(s) = arg.cast::<Scene>() {
        s.get().inner.clone()
    } else if let Ok(s) = arg.extract::<String>() {
        HostScene::open(&s).map_err(|e| scene_error(py, &e))?
    } else if let Ok(p) = arg.extract::<PathBuf>() {
        HostScene::load(&p).map_err(|e| scene_error(py, &e))?
    } else {
        return Err(PyTypeError::new_err(format!(
            "scene: expected a needle.Scene, a scene name or a path, got a {}",
            arg.get_type().name()?
        )));
    };
    let pairs = override_pairs(overrides)?;
    if pairs.is_empty() {
        return Ok(scene);
    }
    scene
        .with_overrides(&pairs)
        .map_err(|e| scene_error(py, &e))
}

fn vec3<'py>(py: Python<'py>, v: &Vector3<f64>) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, &[v.x, v.y, v.z])
}

fn points<'py, 'a>(
    py: Python<'py>,
    pts: impl ExactSizeIterator<Item = &'a Vector3<f64>>,
) -> Bound<'py, PyArray2<f64>> {
    let n = pts.len();
    let flat: Vec<f64> = pts.flat_map(|p| [p.x, p.y, p.z]).collect();
    rows(py, flat, n, 3)
}

fn rows<'py, T: numpy::Element>(
    py: Python<'py>,
    flat: Vec<T>,
    n: usize,
    width: usize,
) -> Bound<'py, PyArray2<T>> {
    Array2::from_shape_vec((n, width), flat)
        .expect("n × width values")
        .into_pyarray(py)
}

fn indices<'py, const K: usize>(
    py: Python<'py>,
    items: &[[usize; K]],
) -> Bound<'py, PyArray2<i64>> {
    let flat = items.iter().flatten().map(|&i| i as i64).collect();
    rows(py, flat, items.len(), K)
}

/// The stage names of [`StageTimes`], in the order of a step, and `total`.
const STAGES: [&str; 7] = ["fm", "cd", "cc", "sc", "corr", "interact", "total"];

fn stage_values(t: &StageTimes) -> [f64; 7] {
    [t.fm, t.cd, t.cc, t.sc, t.corr, t.interact, t.total()]
}

/// One scene: an embedded one (`"simple"`, `"complex"`) or a TOML file, with overrides.
///
/// `Scene(scene, overrides=None)`: `scene` is the name of an embedded scene or a path (a
/// `str` ending in `.toml` or naming an existing file, or an `os.PathLike`), as `needle run`
/// takes it; `overrides` maps dotted fields to values, e.g.
/// `{"gel.box.nodes": 600, "inverse.method": "paper"}` (as `--set`, see docs/scene-format.md).
#[pyclass(module = "needle", frozen)]
struct Scene {
    inner: HostScene,
}

#[pymethods]
impl Scene {
    #[new]
    #[pyo3(signature = (scene, overrides = None))]
    fn new(
        py: Python<'_>,
        scene: &Bound<'_, PyAny>,
        overrides: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        Ok(Self {
            inner: load_scene(py, scene, overrides)?,
        })
    }

    /// A scene from TOML text; `name` stands for the file in error messages.
    #[staticmethod]
    #[pyo3(signature = (text, name = "<string>"))]
    fn from_toml(py: Python<'_>, text: &str, name: &str) -> PyResult<Self> {
        HostScene::from_toml_str(text, name)
            .map(|inner| Self { inner })
            .map_err(|e| scene_error(py, &e))
    }

    /// This scene with `overrides` applied (a new scene).
    fn with_overrides(&self, py: Python<'_>, overrides: &Bound<'_, PyDict>) -> PyResult<Self> {
        let pairs = override_pairs(Some(overrides))?;
        self.inner
            .with_overrides(&pairs)
            .map(|inner| Self { inner })
            .map_err(|e| scene_error(py, &e))
    }

    /// The scene's name.
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }

    /// Steps a run of the scene plans: its `insertion.steps`, else a whole insertion.
    #[getter]
    fn planned_steps(&self) -> usize {
        needle_host::setup::planned_steps(&self.inner)
    }

    /// The scene as TOML text (every field, defaults included).
    fn to_toml(&self) -> PyResult<String> {
        toml::to_string(&self.inner).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    fn __repr__(&self) -> String {
        format!("needle.Scene({:?})", self.inner.name)
    }
}

/// What one step did (`Simulation.step()`, and the argument of `run`'s callback). Lengths in
/// mm, forces in N, times in ms.
#[pyclass(module = "needle", frozen)]
struct StepReport {
    r: HostReport,
}

#[pymethods]
impl StepReport {
    /// Step index (0-based).
    #[getter]
    fn step(&self) -> usize {
        self.r.step
    }
    /// Target's arc length from the start tip [mm].
    #[getter]
    fn c(&self) -> f64 {
        self.r.c
    }
    /// Tip after the step, shape (3,) [mm].
    #[getter]
    fn tip<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec3(py, &self.r.tip)
    }
    /// Target after the step, shape (3,) [mm].
    #[getter]
    fn target<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec3(py, &self.r.target)
    }
    /// `|tip − target|` [mm].
    #[getter]
    fn error(&self) -> f64 {
        self.r.error
    }
    /// Tip distance past the entry point [mm] (0 before the puncture).
    #[getter]
    fn depth(&self) -> f64 {
        self.r.depth
    }
    /// Whether the tip has punctured the surface.
    #[getter]
    fn punctured(&self) -> bool {
        self.r.inserted
    }
    /// Whether the puncture happened during this step.
    #[getter]
    fn punctured_now(&self) -> bool {
        self.r.punctured_now
    }
    /// Whether the tip was inside the gel at this step: punctured, and not the step that
    /// punctured (it ends on the indented surface). The steps of e_mean and e_max.
    #[getter]
    fn inside(&self) -> bool {
        self.r.tip_inside()
    }
    /// Constraint rows of the step.
    #[getter]
    fn rows(&self) -> usize {
        self.r.rows
    }
    /// Sliding points.
    #[getter]
    fn sliding_points(&self) -> usize {
        self.r.sliding_points
    }
    /// Normal force of the tip contact [N].
    #[getter]
    fn contact_force(&self) -> f64 {
        self.r.contact_force
    }
    /// Largest constraint violation after the step over the non-base bilateral rows [mm].
    #[getter]
    fn residual(&self) -> f64 {
        self.r.residual
    }
    /// Gauss-Seidel sweeps of the step, all solves.
    #[getter]
    fn gs_iterations(&self) -> u32 {
        self.r.solver.iterations
    }
    /// Joints after the step, shape (joints,) [rad]: 6, or 7 for a 7-joint arm.
    #[getter]
    fn joints<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.r.q)
    }
    /// Wall time of each stage [ms]: `fm` free motion, `cd` proximity, `cc` compliance, `sc`
    /// constraint solves (the core), `corr` corrective motion, `interact` puncture and sliding
    /// points, and `total`.
    #[getter]
    fn times<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (k, v) in STAGES.iter().zip(stage_values(&self.r.times)) {
            d.set_item(k, v)?;
        }
        Ok(d)
    }

    /// Every field as a dict (arrays as NumPy arrays).
    fn to_dict<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyDict>> {
        let py = slf.py();
        let d = PyDict::new(py);
        for k in [
            "step",
            "c",
            "tip",
            "target",
            "error",
            "depth",
            "punctured",
            "punctured_now",
            "inside",
            "rows",
            "sliding_points",
            "contact_force",
            "residual",
            "gs_iterations",
            "joints",
            "times",
        ] {
            d.set_item(k, slf.getattr(k)?)?;
        }
        Ok(d)
    }

    fn __repr__(&self) -> String {
        let r = &self.r;
        format!(
            "needle.StepReport(step={}, c={:.3}, error={:.4}, depth={:.3}, punctured={}, \
             total_ms={:.3})",
            r.step,
            r.c,
            r.error,
            r.depth,
            if r.inserted { "True" } else { "False" },
            r.times.total()
        )
    }
}

/// The state of a [`Simulation`] of a robot of `N` joints.
struct State<const N: usize> {
    world: World<N>,
    params: StepParams,
    core: InProcess<ROWS, N>,
    pipeline: Pipeline<N>,
    plan: Plan,
    /// Why a step failed: the world may be half-way through it and is not stepped again.
    failed: Option<String>,
}

impl<const N: usize> State<N> {
    /// The state at the start of `setup`.
    fn new(setup: Setup<N>) -> Self {
        let core = InProcess::<ROWS, N>::new(setup.robot, setup.inverse);
        let pipeline = Pipeline::new(&setup.world);
        Self {
            world: setup.world,
            params: setup.params,
            core,
            pipeline,
            plan: setup.plan,
            failed: None,
        }
    }

    /// One step, or why it failed (then, and after an earlier failure, the state is not
    /// stepped).
    fn step(&mut self) -> Result<HostReport, String> {
        if let Some(why) = &self.failed {
            return Err(format!("an earlier step failed ({why}): cannot step again"));
        }
        match self.pipeline.step(&mut self.world, &self.params, &mut self.core) {
            Ok(r) => Ok(r),
            Err(e) => {
                let why = chain(&e);
                self.failed = Some(why.clone());
                Err(why)
            }
        }
    }
}

/// A [`State`] of the scene's own joint count (the counts the host runs: 6 and 7).
enum States {
    J6(State<6>),
    J7(State<7>),
}

/// `$body` on the [`State`] of a [`Simulation`] (`$s`), whatever its joint count.
macro_rules! with_state {
    ($sim:expr, |$s:ident| $body:expr) => {{
        let guard = $sim.lock();
        match &*guard {
            States::J6($s) => $body,
            States::J7($s) => $body,
        }
    }};
}

/// Sets a scene up with its robot's own joint count ([`with_setup`]) into a [`States`].
struct BuildState;

impl WithSetup for BuildState {
    type Output = Result<States, String>;
    fn with<const N: usize>(self, setup: Setup<N>) -> Self::Output {
        if setup.model.is_some() {
            // A hidden support motion steps two worlds (the controller's model and the moving
            // world); a Simulation steps one.
            return Err("gel.support_motion.hidden: a Simulation steps one world; run a motion \
                        hidden from the model with needle.run"
                .into());
        }
        let state: Box<dyn Any> = Box::new(State::<N>::new(setup));
        match state.downcast::<State<6>>() {
            Ok(s) => Ok(States::J6(*s)),
            Err(state) => match state.downcast::<State<7>>() {
                Ok(s) => Ok(States::J7(*s)),
                Err(_) => Err(format!("a robot of {N} joints: a Simulation steps 6 or 7")),
            },
        }
    }
}

/// A scene set up and stepped from Python, one step at a time, with the core in this process
/// (as `host/examples/run_scene.rs`): no watchdog, no settling, no summary — see `run` for
/// those. The robot has the scene's joint count (6, or 7 for a 7-joint arm such as
/// `scenes/robots/iiwa_complex.toml`): `joints` arrays have that length.
///
/// `Simulation(scene, overrides=None)` takes what `Scene` takes (or a `Scene`).
#[pyclass(module = "needle")]
struct Simulation {
    state: Mutex<States>,
    name: String,
}

impl Simulation {
    fn lock(&self) -> std::sync::MutexGuard<'_, States> {
        // A panic in a step poisons the lock; the state is then flagged failed anyway.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

#[pymethods]
impl Simulation {
    #[new]
    #[pyo3(signature = (scene, overrides = None))]
    fn new(
        py: Python<'_>,
        scene: &Bound<'_, PyAny>,
        overrides: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let scene = load_scene(py, scene, overrides)?;
        let state = py
            .detach(|| with_setup(&scene, BuildState))
            .map_err(|e| SetupError::new_err(chain(&e)))?
            .map_err(SetupError::new_err)?;
        Ok(Self {
            state: Mutex::new(state),
            name: scene.name,
        })
    }

    /// Runs one step (free motion, proximity, compliance, the core's inverse step, corrective
    /// motion) and returns its report. Raises `SimulationError` if the step fails; the
    /// simulation cannot be stepped after that.
    fn step(&self, py: Python<'_>) -> PyResult<StepReport> {
        py.detach(|| match &mut *self.lock() {
            States::J6(s) => s.step(),
            States::J7(s) => s.step(),
        })
        .map(|r| StepReport { r })
        .map_err(SimulationError::new_err)
    }

    /// The scene's name.
    #[getter]
    fn name(&self) -> &str {
        &self.name
    }
    /// Steps a run of the scene plans (a whole insertion, or its `insertion.steps`).
    #[getter]
    fn planned_steps(&self) -> usize {
        with_state!(self, |s| s.plan.steps)
    }
    /// Steps done.
    #[getter]
    fn steps(&self) -> usize {
        with_state!(self, |s| s.world.steps)
    }
    /// Time step [s].
    #[getter]
    fn dt(&self) -> f64 {
        with_state!(self, |s| s.params.dt)
    }
    /// Target's arc length from the start tip [mm].
    #[getter]
    fn c(&self) -> f64 {
        with_state!(self, |s| s.world.c)
    }
    /// Needle tip, shape (3,) [mm].
    #[getter]
    fn tip<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec3(py, &with_state!(self, |s| s.world.tip()))
    }
    /// Current target (the path point at arc length `c`; embedded in the gel once punctured),
    /// shape (3,) [mm].
    #[getter]
    fn target<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec3(py, &with_state!(self, |s| s.world.target(s.world.c)))
    }
    /// `|tip − target|` [mm].
    #[getter]
    fn error(&self) -> f64 {
        with_state!(self, |s| (s.world.tip() - s.world.target(s.world.c)).norm())
    }
    /// Insertion depth: tip distance past the entry point, 0 before the puncture [mm].
    #[getter]
    fn depth(&self) -> f64 {
        with_state!(self, |s| s.world.depth())
    }
    /// Whether the tip has punctured the surface.
    #[getter]
    fn punctured(&self) -> bool {
        with_state!(self, |s| s.world.punctured)
    }
    /// Whether the tip pushed on the surface in the last step.
    #[getter]
    fn in_contact(&self) -> bool {
        with_state!(self, |s| s.world.in_contact)
    }
    /// The robot's joints, shape (joints,) [rad]: 6, or 7 for a 7-joint arm.
    #[getter]
    fn joints<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        with_state!(self, |s| PyArray1::from_slice(py, &s.world.q))
    }
    /// The robot's joint count: 6, or 7 for a 7-joint arm.
    #[getter]
    fn joint_count(&self) -> usize {
        with_state!(self, |s| s.world.q.len())
    }
    /// Needle nodes, base first, tip last, shape (N, 3) [mm].
    #[getter]
    fn needle_positions<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        with_state!(self, |s| points(py, s.world.needle.positions().iter()))
    }
    /// Gel nodes, shape (N, 3) [mm].
    #[getter]
    fn gel_positions<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        with_state!(self, |s| points(py, s.world.gel.positions().iter()))
    }
    /// Gel nodes at rest, shape (N, 3) [mm].
    #[getter]
    fn gel_rest_positions<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        with_state!(self, |s| points(py, s.world.gel.mesh().nodes.iter()))
    }
    /// The gel's tetrahedra as node indices, shape (M, 4).
    #[getter]
    fn gel_tets<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        with_state!(self, |s| indices(py, &s.world.gel.mesh().tets))
    }
    /// The gel's surface triangles as node indices, shape (K, 3).
    #[getter]
    fn gel_surface<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        with_state!(self, |s| indices(py, &s.world.surface))
    }
    /// The entry point (planned before the puncture, actual after), shape (3,) [mm].
    #[getter]
    fn entry_point<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec3(py, &with_state!(self, |s| s.world.entry_point()))
    }
    /// Clearance of the inserted needle to each obstacle (negative: hit; `inf` before the
    /// puncture), shape (obstacles,) [mm].
    #[getter]
    fn clearances<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, with_state!(self, |s| s.world.clearances()))
    }

    fn __repr__(&self) -> String {
        with_state!(self, |s| {
            format!(
                "needle.Simulation({:?}, steps={}, c={:.3}, depth={:.3})",
                self.name,
                s.world.steps,
                s.world.c,
                s.world.depth()
            )
        })
    }
}

/// What `run` returns: the summary (`needle run --json`'s, as a dict) and every step's values
/// as NumPy arrays, one row per step.
#[pyclass(module = "needle", frozen)]
struct RunResult {
    summary: Py<PyDict>,
    reports: Vec<HostReport>,
    error_by_depth: Vec<(f64, f64)>,
}

impl RunResult {
    fn column<'py>(
        &self,
        py: Python<'py>,
        f: impl Fn(&HostReport) -> f64,
    ) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.reports.iter().map(f).collect())
    }
}

#[pymethods]
impl RunResult {
    /// The run's summary: outcome, e_mean_mm, e_max_mm, e_final_mm, timing, clearances, …
    /// (the keys of `needle run --json`, docs/architecture.md "Run metrics and outcome").
    #[getter]
    fn summary<'py>(&self, py: Python<'py>) -> Bound<'py, PyDict> {
        self.summary.bind(py).clone()
    }
    /// The outcome: `reached`, `missed_target`, `obstacle_hit`, `diverged` or `left_path`.
    #[getter]
    fn outcome(&self, py: Python<'_>) -> PyResult<String> {
        self.summary
            .bind(py)
            .get_item("outcome")?
            .ok_or_else(|| PyRuntimeError::new_err("the summary has no outcome"))?
            .extract()
    }
    /// Step indices, shape (steps,).
    #[getter]
    fn steps<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        PyArray1::from_vec(py, self.reports.iter().map(|r| r.step as i64).collect())
    }
    /// Target arc length per step, shape (steps,) [mm].
    #[getter]
    fn c<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.column(py, |r| r.c)
    }
    /// Tracking error per step, shape (steps,) [mm].
    #[getter]
    fn errors<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.column(py, |r| r.error)
    }
    /// Insertion depth per step, shape (steps,) [mm].
    #[getter]
    fn depths<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.column(py, |r| r.depth)
    }
    /// Whether the tip had punctured the surface, per step, shape (steps,).
    #[getter]
    fn punctured<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<bool>> {
        PyArray1::from_vec(py, self.reports.iter().map(|r| r.inserted).collect())
    }
    /// Whether the tip was inside the gel, per step, shape (steps,): punctured, and not the
    /// step that punctured (it ends on the indented surface). The steps of e_mean and e_max.
    #[getter]
    fn inside<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<bool>> {
        PyArray1::from_vec(py, self.reports.iter().map(|r| r.tip_inside()).collect())
    }
    /// Tip per step, shape (steps, 3) [mm].
    #[getter]
    fn tips<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        points(py, self.reports.iter().map(|r| &r.tip))
    }
    /// Target per step, shape (steps, 3) [mm].
    #[getter]
    fn targets<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        points(py, self.reports.iter().map(|r| &r.target))
    }
    /// Joints per step, shape (steps, joints) [rad]: 6 joints, or 7 for a 7-joint arm.
    #[getter]
    fn joints<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let n = self.reports.first().map_or(6, |r| r.q.len());
        let flat = self.reports.iter().flat_map(|r| r.q).collect();
        rows(py, flat, self.reports.len(), n)
    }
    /// Wall time of each stage per step [ms]: a dict of arrays of shape (steps,), keys `fm`,
    /// `cd`, `cc`, `sc`, `corr`, `interact`, `total` (see `StepReport.times`).
    #[getter]
    fn stage_times<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (i, k) in STAGES.iter().enumerate() {
            d.set_item(k, self.column(py, |r| stage_values(&r.times)[i]))?;
        }
        Ok(d)
    }
    /// `(depth, error)` of the steps with the tip inside the gel, shape (k, 2) [mm].
    #[getter]
    fn error_by_depth<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let flat = self
            .error_by_depth
            .iter()
            .flat_map(|&(d, e)| [d, e])
            .collect();
        rows(py, flat, self.error_by_depth.len(), 2)
    }
    /// Every step's report.
    #[getter]
    fn reports(&self) -> Vec<StepReport> {
        self.reports
            .iter()
            .map(|r| StepReport { r: r.clone() })
            .collect()
    }

    fn __len__(&self) -> usize {
        self.reports.len()
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let s = self.summary.bind(py);
        let get = |k: &str| {
            s.get_item(k)
                .ok()
                .flatten()
                .map_or_else(|| "?".to_owned(), |v| v.to_string())
        };
        format!(
            "needle.RunResult(scene={}, steps={}, outcome={}, e_mean_mm={}, e_max_mm={})",
            get("scene"),
            self.reports.len(),
            get("outcome"),
            get("e_mean_mm"),
            get("e_max_mm")
        )
    }
}

/// Runs a scene to the end, as `needle run` does, and returns a `RunResult`.
///
/// `run(scene, overrides=None, *, callback=None, steps=None, controller="inverse", out=None,
/// vtk_every=None)`:
/// - `scene`, `overrides`: as `Scene` (or a `Scene`);
/// - `callback(report)`: called after every step with its `StepReport`; an exception raised
///   in it (or Ctrl-C) stops the run after that step and propagates;
/// - `steps`: the number of steps (default: the whole insertion, with its settling steps);
/// - `controller`: `"inverse"` (the paper's method) or `"naive"` (the rigid-IK baseline);
/// - `out`, `vtk_every`: write `needle run --out`'s files (steps.csv, VTK, summary.json,
///   replay.html) into the folder `out`.
///
/// The loop is the host's `run` (`Setup::build`, the core in this process, `run_setup`): the
/// same watchdog, settling steps and outcome as `needle run`, and the same figures.
#[pyfunction]
#[pyo3(signature = (scene, overrides = None, *, callback = None, steps = None,
                    controller = "inverse", out = None, vtk_every = None))]
#[allow(clippy::too_many_arguments)]
fn run(
    py: Python<'_>,
    scene: &Bound<'_, PyAny>,
    overrides: Option<&Bound<'_, PyDict>>,
    callback: Option<Py<PyAny>>,
    steps: Option<usize>,
    controller: &str,
    out: Option<PathBuf>,
    vtk_every: Option<usize>,
) -> PyResult<RunResult> {
    let scene = load_scene(py, scene, overrides)?;
    let controller = match controller {
        "inverse" => ControllerKind::Inverse,
        "naive" => ControllerKind::Naive,
        other => {
            return Err(PyValueError::new_err(format!(
                "controller: `{other}` is neither \"inverse\" nor \"naive\""
            )));
        }
    };
    if let Some(n) = steps
        && !(1..=MAX_STEPS).contains(&n)
    {
        return Err(PyValueError::new_err(format!(
            "steps: must be between 1 and {MAX_STEPS} (got {n})"
        )));
    }
    if vtk_every.is_some() && out.is_none() {
        return Err(PyValueError::new_err(
            "vtk_every: VTK files are written into the `out` folder: give out",
        ));
    }
    let opts = RunOptions {
        controller,
        steps,
        out_dir: out,
        vtk_every,
        ..RunOptions::default()
    };
    let mut raised: Option<PyErr> = None;
    // The step loop runs without the GIL; the callback takes it back for each step. When the
    // callback raises (or Ctrl-C arrives), the run stops right after that step through the
    // host's own early stop (`run_until`: the files and the summary are written as for any end)
    // and the error is raised here.
    let result = py.detach(|| {
        needle_host::run::run_until(&scene, &opts, |r| {
            let result = Python::attach(|py| {
                py.check_signals()?;
                match &callback {
                    Some(cb) => cb.call1(py, (StepReport { r: r.clone() },)).map(drop),
                    None => Ok(()),
                }
            });
            match result {
                Ok(()) => ControlFlow::Continue(()),
                Err(e) => {
                    raised = Some(e);
                    ControlFlow::Break(())
                }
            }
        })
    });
    if let Some(e) = raised {
        return Err(e);
    }
    let result = result.map_err(|e| run_error(&e))?;
    let json = serde_json::to_string(&result.summary)
        .map_err(|e| SimulationError::new_err(format!("summary: {e}")))?;
    let summary = py
        .import("json")?
        .call_method1("loads", (json,))?
        .cast_into::<PyDict>()?
        .unbind();
    Ok(RunResult {
        summary,
        reports: result.reports,
        error_by_depth: result.error_by_depth,
    })
}

/// Inverse real-time FE control of robotic needle insertion: scenes, a simulation stepped from
/// Python, and whole runs as `needle run` makes them.
#[pymodule]
fn needle(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<Scene>()?;
    m.add_class::<Simulation>()?;
    m.add_class::<StepReport>()?;
    m.add_class::<RunResult>()?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add("SceneError", py.get_type::<SceneError>())?;
    m.add("SetupError", py.get_type::<SetupError>())?;
    m.add("SimulationError", py.get_type::<SimulationError>())?;
    m.add("BUILTIN_SCENES", HostScene::BUILTIN.to_vec())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
