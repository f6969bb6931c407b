//! Loading a scene: TOML text or file → [`Scene`] (parsed, then validated), the embedded
//! benchmark scenes, and dotted-path overrides. Every error names the file, the field and the
//! reason ([`SceneError`]).

use super::{COMPLEX_TOML, GelSpec, PathError, SIMPLE_TOML, SampledPath, Scene};
use crate::joints::{WithJoints, with_joints};
use std::fmt;
use std::path::Path;

/// What went wrong loading a scene: the file, the field and the reason.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    /// The scene file (or `<builtin:NAME>`).
    pub file: String,
    /// Dotted path of the offending field, e.g. `gel.young_modulus` (empty for a syntax error).
    pub field: String,
    /// Why it was rejected.
    pub reason: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.field.is_empty() {
            write!(f, "{}: {}", self.file, self.reason)
        } else {
            write!(f, "{}: field `{}`: {}", self.file, self.field, self.reason)
        }
    }
}

impl std::error::Error for SceneError {}

impl Scene {
    /// Parses and validates a scene from TOML text; `file` names it in errors.
    ///
    /// # Errors
    /// [`SceneError`] naming the file, the field and the reason for a syntax error, an unknown or
    /// missing field, a value of the wrong type, or a value that makes no physical sense.
    pub fn from_toml_str(text: &str, file: &str) -> Result<Self, SceneError> {
        let de = toml::Deserializer::parse(text).map_err(|e| SceneError {
            file: file.to_owned(),
            field: String::new(),
            reason: one_line(&e.to_string()),
        })?;
        let mut scene: Scene = serde_path_to_error::deserialize(de).map_err(|e| {
            let field = e.path().to_string();
            SceneError {
                file: file.to_owned(),
                field: if field == "." { String::new() } else { field },
                reason: one_line(&e.into_inner().to_string()),
            }
        })?;
        if scene.gel.box_mesh.is_none() && scene.gel.mesh.is_none() {
            scene.gel.box_mesh = GelSpec::default().box_mesh;
        }
        scene.validate().map_err(|(field, reason)| SceneError {
            file: file.to_owned(),
            field,
            reason,
        })?;
        Ok(scene)
    }

    /// Largest scene file read [bytes].
    pub const MAX_SCENE_BYTES: u64 = 1 << 20;

    /// Reads, parses and validates a scene file. Relative mesh paths are resolved against its folder.
    ///
    /// # Errors
    /// [`SceneError`] for an unreadable file or any error of [`Scene::from_toml_str`].
    pub fn load(path: &Path) -> Result<Self, SceneError> {
        let file = path.display().to_string();
        let cannot = |e: &dyn std::fmt::Display| SceneError {
            file: file.clone(),
            field: String::new(),
            reason: format!("cannot read: {e}"),
        };
        let bytes = crate::bounded_read::read_bounded(path, Self::MAX_SCENE_BYTES)
            .map_err(|e| cannot(&e))?;
        let text = String::from_utf8(bytes).map_err(|e| cannot(&e))?;
        let mut scene = Self::from_toml_str(&text, &file)?;
        if let (Some(mesh), Some(dir)) = (scene.gel.mesh.as_mut(), path.parent())
            && mesh.is_relative()
        {
            *mesh = dir.join(&*mesh);
        }
        if let (Some(csv), Some(dir)) = (
            scene
                .gel
                .support_motion
                .as_mut()
                .and_then(|m| m.csv.as_mut()),
            path.parent(),
        ) && csv.is_relative()
        {
            *csv = dir.join(&*csv);
        }
        // Obstacle meshes: resolved against the scene's folder and read now, so that a bad
        // file is refused naming the scene, the field and the mesh file.
        for (k, o) in scene.obstacles.iter_mut().enumerate() {
            if let Some(mesh) = o.mesh.as_mut() {
                if let Some(dir) = path.parent()
                    && mesh.is_relative()
                {
                    *mesh = dir.join(&*mesh);
                }
                crate::obstacle_mesh::read_surface_mesh(mesh, o.physical_group.as_ref()).map_err(
                    |e| SceneError {
                        file: file.clone(),
                        field: format!(
                            "obstacles[{k}].{}",
                            if e.in_group { "physical_group" } else { "mesh" }
                        ),
                        reason: format!("{}: {}", mesh.display(), e.reason),
                    },
                )?;
            }
        }
        if let (Some(urdf), Some(dir)) = (scene.robot.urdf.as_mut(), path.parent())
            && urdf.is_relative()
        {
            *urdf = dir.join(&*urdf);
        }
        // The URDF is read once its path is resolved: its chain, and the start joints against
        // its limits.
        if scene.robot.urdf.is_some() {
            scene
                .joint_count()
                .and_then(|n| {
                    struct Check<'a>(&'a Scene);
                    impl WithJoints for Check<'_> {
                        type Output = Result<(), (String, String)>;
                        fn with<const N: usize>(self) -> Self::Output {
                            self.0.check_start_joints(&self.0.robot_n::<N>()?)
                        }
                    }
                    // `joint_count` gives only the counts `with_joints` runs.
                    with_joints(n, Check(&scene)).unwrap_or(Ok(()))
                })
                .map_err(|(field, reason)| SceneError {
                    file: file.clone(),
                    field,
                    reason,
                })?;
        }
        Ok(scene)
    }

    /// The scene a command line names: a file (an existing path, or any name ending in
    /// `.toml`), else an embedded scene.
    ///
    /// # Errors
    /// [`SceneError`] for a file that cannot be loaded, or a name that is neither.
    ///
    /// # Example
    /// ```
    /// use needle_host::scene::Scene;
    ///
    /// assert_eq!(Scene::open("simple").unwrap().name, "simple");
    /// let e = Scene::open("nowhere").unwrap_err();
    /// assert!(e.to_string().contains("neither a scene file nor an embedded scene"));
    /// ```
    pub fn open(arg: &str) -> Result<Self, SceneError> {
        let p = Path::new(arg);
        // A file wins; an embedded name wins over a folder of the same name (`--out simple`).
        if p.is_file() || arg.ends_with(".toml") {
            return Self::load(p);
        }
        if let Some(scene) = Self::builtin(arg) {
            return Ok(scene);
        }
        if p.exists() {
            return Self::load(p);
        }
        Err(SceneError {
            file: arg.to_owned(),
            field: String::new(),
            reason: format!(
                "neither a scene file nor an embedded scene ({})",
                Self::BUILTIN.join(", ")
            ),
        })
    }

    /// One of the embedded benchmark scenes: `"simple"` or `"complex"`.
    pub fn builtin(name: &str) -> Option<Self> {
        let text = match name {
            "simple" => SIMPLE_TOML,
            "complex" => COMPLEX_TOML,
            _ => return None,
        };
        Self::from_toml_str(text, &format!("<builtin:{name}>")).ok()
    }

    /// The scene with `overrides` applied: each `(path, value)` sets the dotted field `path`
    /// (e.g. `inverse.delta_q`) to `value`, a TOML value (`0.001`, `"solve"`, `[1, 2, 3]`).
    ///
    /// # Errors
    /// [`SceneError`] naming the field when the path does not exist, the value does not parse or
    /// the result fails validation.
    pub fn with_overrides(&self, overrides: &[(String, String)]) -> Result<Self, SceneError> {
        let file = format!("<{} + overrides>", self.name);
        let err = |field: &str, reason: String| SceneError {
            file: file.clone(),
            field: field.to_owned(),
            reason,
        };
        let mut root = toml::Value::try_from(self).map_err(|e| err("", e.to_string()))?;
        for (path, value) in overrides {
            let parsed: toml::Value = toml::from_str::<toml::Table>(&format!("v = {value}"))
                .map_err(|e| {
                    err(
                        path,
                        format!(
                            "`{value}` is not a TOML value: {}",
                            one_line(&e.to_string())
                        ),
                    )
                })?
                .remove("v")
                .ok_or_else(|| err(path, format!("`{value}` is not a TOML value")))?;
            let mut node = &mut root;
            let keys: Vec<&str> = path.split('.').collect();
            for (i, k) in keys.iter().enumerate() {
                let table = node.as_table_mut().ok_or_else(|| {
                    err(path, format!("`{}` is not a table", keys[..i].join(".")))
                })?;
                if i + 1 == keys.len() {
                    table.insert((*k).to_owned(), parsed.clone());
                    break;
                }
                node = table
                    .entry((*k).to_owned())
                    .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            }
        }
        let text = toml::to_string(&root).map_err(|e| err("", e.to_string()))?;
        // A loaded scene's mesh path is already resolved, so the text round trip keeps it.
        Self::from_toml_str(&text, &file)
    }

    /// Names of the embedded scenes.
    pub const BUILTIN: [&'static str; 2] = ["simple", "complex"];

    /// Samples the path into a polyline with arc length (rest configuration).
    ///
    /// # Errors
    /// [`PathError`] when a formula does not parse or evaluates to a non-finite value.
    pub fn sampled_path(&self) -> Result<SampledPath, PathError> {
        SampledPath::from_spec(&self.path)
    }
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}
