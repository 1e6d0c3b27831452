//! Python bindings of cosem: semantic voxel maps and their alignment,
//! linking the core directly (no call to the `cosem` binary).
//!
//! ```python
//! import cosem
//! a, b = cosem.Map.load("a.cmap"), cosem.Map.load("b.cmap")
//! r = cosem.match(a, b)          # no prior; or init=4x4 T_model_scene
//! print(r.status, r.transform)   # "Converged", 4x4 numpy array
//! ```

use cosem_core::classes::Class;
use cosem_core::geometry::Isometry3;
use cosem_core::map::{LabelDistribution, MapConfig};
use cosem_core::matching::{MatchResult, MatchSettings};
use cosem_host::maps::mapping::{build_map, BuildError, HostMap, PointFilter, Unlabeled};
use cosem_host::matching::align::{align, prepare, DEFAULT_LEVELS};
use cosem_host::sources::kitti::Frame;
use numpy::{PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::{PyIOError, PyValueError};
use pyo3::prelude::*;

/// A semantic voxel map (a robot's local map).
#[pyclass(module = "cosem")]
struct Map {
    map: HostMap,
}

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

#[pymethods]
impl Map {
    /// Reads a `.cmap` map file.
    #[staticmethod]
    fn load(path: std::path::PathBuf) -> PyResult<Self> {
        let (_, map) = cosem_host::maps::cmap::read(&path).map_err(|e| PyIOError::new_err(e.to_string()))?;
        Ok(Map { map })
    }

    /// Writes the map as a `.cmap` file.
    fn save(&self, path: std::path::PathBuf) -> PyResult<()> {
        cosem_host::maps::cmap::write(&path, &self.map, None, Some("cosem python"))
            .map(|_| ())
            .map_err(|e| PyIOError::new_err(e.to_string()))
    }

    /// A map of labelled points: `xyz` an (N, 3) array of numbers in the
    /// map's frame (m; any float or integer dtype, converted to float64),
    /// `labels` N non-negative integers of any integer dtype, each holding
    /// the SemanticKITTI id in its low 16 bits (an instance id may sit in
    /// the bits above), voxels of `voxel` metres (default: the host pipeline's, 0.2). Points without a class
    /// (unlabeled, outliers, moving objects) are left out; with
    /// `unlabeled="geometry"` unlabelled points (id 0: a camera's labels
    /// leave so the points outside its view) are kept as voxels of an
    /// unknown class (class index 255 in `voxels()`), which matching takes
    /// as uniform over the classes. A negative label, a NaN coordinate, an
    /// `unlabeled` other than "drop" or "geometry", or a map left empty is a
    /// `ValueError` saying why.
    #[staticmethod]
    #[pyo3(signature = (xyz, labels, voxel = None, unlabeled = "drop"))]
    fn from_points(
        xyz: &Bound<'_, PyAny>,
        labels: &Bound<'_, PyAny>,
        voxel: Option<f32>,
        unlabeled: &str,
    ) -> PyResult<Self> {
        // The host's pipeline unless told (0.2 m).
        let voxel = voxel.unwrap_or(cosem_core::pipeline::Pipeline::HOST.voxel);
        let unlabeled: Unlabeled = unlabeled.parse().map_err(|e: String| value_error(format!("unlabeled={e}")))?;
        // The host's filter (no range limit, moving objects left out).
        let filter = PointFilter { unlabeled, ..PointFilter::default() };
        let xyz = float_array(xyz, "xyz", "(N, 3)")?;
        let xyz: PyReadonlyArray2<'_, f64> = xyz.extract().map_err(|_| value_error(xyz_shape_error(&xyz)))?;
        let shape = xyz.shape();
        if shape[1] != 3 {
            return Err(value_error(format!("xyz must be an (N, 3) array, got shape {shape:?}")));
        }
        let labels = label_words(labels, shape[0])?;
        let points: Vec<[f32; 3]> =
            xyz.as_array().outer_iter().map(|p| [p[0] as f32, p[1] as f32, p[2] as f32]).collect();
        // One frame at the origin through the host's one mapping path
        // (what `cosem map` runs): ranges 0, so no range limit applies.
        let frame = Frame {
            index: 0,
            time: None,
            pose: nalgebra::Isometry3::identity(),
            ranges: vec![0.0; points.len()],
            points,
            labels,
            evidence: None,
        };
        let config = MapConfig { resolution: voxel, ..MapConfig::default() };
        let (map, _) = build_map(&[frame], config, &filter).map_err(|e| match e {
            BuildError::Empty(_) if shape[0] == 0 => value_error("no points: the map would be empty"),
            e => value_error(e),
        })?;
        Ok(Map { map })
    }

    /// A map from voxels as [`Map.voxels`] gives them: `positions` an (N, 3)
    /// array (m), `classes` N class indices (0-18, the positions in
    /// `cosem.CLASSES`, or 255 for an unknown class; not label ids). Each voxel is re-created holding
    /// one observation at its position: the same voxels and classes, with
    /// the observation counts and confidences of a fresh map.
    #[staticmethod]
    #[pyo3(signature = (positions, classes, voxel = 0.2))]
    fn from_voxels(positions: &Bound<'_, PyAny>, classes: &Bound<'_, PyAny>, voxel: f32) -> PyResult<Self> {
        let positions = float_array(positions, "positions", "(N, 3)")?;
        let positions: PyReadonlyArray2<'_, f64> =
            positions.extract().map_err(|_| value_error(xyz_shape_error(&positions)))?;
        let shape = positions.shape();
        if shape[1] != 3 {
            return Err(value_error(format!("positions must be an (N, 3) array, got shape {shape:?}")));
        }
        let classes = integer_array(classes, "classes", shape[0])?;
        let config = MapConfig { resolution: voxel, ..MapConfig::default() };
        let mut map = cosem_core::map::vec_map(shape[0].max(1), config).map_err(value_error)?;
        for (i, (p, &c)) in positions.as_array().outer_iter().zip(classes.iter()).enumerate() {
            let point = [p[0] as f32, p[1] as f32, p[2] as f32];
            let inserted = if c == 255 {
                map.insert_point_evidence(point, &LabelDistribution::EMPTY)
            } else {
                let class = u8::try_from(c).ok().and_then(Class::from_index).ok_or_else(|| {
                    value_error(format!("classes[{i}] = {c}: not a class index (0 to 18, see cosem.CLASSES, or 255)"))
                })?;
                map.insert_point(point, class)
            };
            inserted.map_err(|e| value_error(format!("voxel {i} {point:?}: {e}")))?;
        }
        if map.is_empty() {
            return Err(value_error("no voxels: the map would be empty".to_string()));
        }
        Ok(Map { map })
    }

    /// The voxels: their mean positions as an (N, 3) float32 array and
    /// their classes as N uint8 class indices into `cosem.CLASSES` (255
    /// without one). These are class indices, not label ids: give them
    /// back to `Map.from_voxels`, not to `Map.from_points`.
    fn voxels<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray1<u8>>) {
        let r = self.map.resolution();
        let positions: Vec<Vec<f32>> = self.map.iter().map(|v| v.position(r).to_vec()).collect();
        let classes: Vec<u8> = self.map.iter().map(|v| v.class().map_or(255, |c| c.index())).collect();
        let positions = if positions.is_empty() {
            numpy::PyArray2::zeros(py, [0, 3], false)
        } else {
            numpy::PyArray2::from_vec2(py, &positions).expect("rows of three")
        };
        (positions, PyArray1::from_vec(py, classes))
    }

    /// Voxel size (m).
    #[getter]
    fn resolution(&self) -> f32 {
        self.map.resolution()
    }

    fn __len__(&self) -> usize {
        self.map.len()
    }

    fn __repr__(&self) -> String {
        format!("cosem.Map({} voxels of {} m)", self.map.len(), self.map.resolution())
    }
}

/// `obj` as a float64 numpy array: any float or integer dtype is
/// converted; another is an error naming the expected dtype and shape.
fn float_array<'py>(obj: &Bound<'py, PyAny>, name: &str, shape: &str) -> PyResult<Bound<'py, PyAny>> {
    let np = obj.py().import("numpy")?;
    let a = np.call_method1("asarray", (obj,))?;
    let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        let dtype = a.getattr("dtype")?.str()?.to_string();
        return Err(value_error(format!(
            "{name} must be a {shape} array of numbers (float64 or any float or integer dtype), got dtype {dtype}"
        )));
    }
    let ndim: usize = a.getattr("ndim")?.extract()?;
    if ndim != 2 {
        let got: Vec<usize> = a.getattr("shape")?.extract()?;
        return Err(value_error(format!("{name} must be a {shape} array, got shape {got:?}")));
    }
    a.call_method1("astype", ("float64",))
}

fn xyz_shape_error(a: &Bound<'_, PyAny>) -> String {
    let got: Vec<usize> = a.getattr("shape").and_then(|s| s.extract()).unwrap_or_default();
    format!("expected an (N, 3) float64 array, got shape {got:?}")
}

/// `obj` as `n` non-negative integers (any integer dtype).
fn integer_array(obj: &Bound<'_, PyAny>, name: &str, n: usize) -> PyResult<Vec<u64>> {
    let np = obj.py().import("numpy")?;
    let a = np.call_method1("asarray", (obj,))?;
    let dtype = a.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    let ndim: usize = a.getattr("ndim")?.extract()?;
    let size: usize = a.getattr("size")?.extract()?;
    if !matches!(kind.as_str(), "i" | "u") || ndim != 1 {
        let got: Vec<usize> = a.getattr("shape")?.extract()?;
        return Err(value_error(format!(
            "{name} must be a 1-D array of N integers (any integer dtype), got dtype {} and shape {got:?}",
            dtype.str()?
        )));
    }
    if size != n {
        return Err(value_error(format!("{n} points but {size} {name}")));
    }
    if kind == "i" && size > 0 {
        let min: i64 = a.call_method0("min")?.extract()?;
        if min < 0 {
            let at: usize = a.call_method0("argmin")?.extract()?;
            return Err(value_error(format!("{name}[{at}] = {min}: a label is never negative")));
        }
    }
    let a = a.call_method1("astype", ("uint64",))?;
    let a: PyReadonlyArray1<'_, u64> = a.extract()?;
    Ok(a.as_array().to_vec())
}

/// Label words of `n` points: the SemanticKITTI id in the low 16 bits.
fn label_words(obj: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<u32>> {
    Ok(integer_array(obj, "labels", n)?.into_iter().map(|l| (l & 0xFFFF) as u32).collect())
}

/// What a match found.
#[pyclass(module = "cosem")]
struct Match {
    result: MatchResult,
}

#[pymethods]
impl Match {
    /// `T_model_scene` as a 4x4 array (float64).
    #[getter]
    fn transform<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let m = self.result.transform.to_homogeneous();
        let rows: Vec<Vec<f64>> = (0..4).map(|r| (0..4).map(|c| f64::from(m[(r, c)])).collect()).collect();
        PyArray2::from_vec2(py, &rows).expect("4x4")
    }

    /// `Converged`, `NotConverged`, `Degenerate` or `NoOverlap`.
    #[getter]
    fn status(&self) -> String {
        self.result.status.as_str().to_owned()
    }

    /// The 6x6 information matrix (x, y, z, roll, pitch, yaw).
    #[getter]
    fn information<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let m = &self.result.information;
        let rows: Vec<Vec<f64>> = (0..6).map(|r| (0..6).map(|c| f64::from(m[(r, c)])).collect()).collect();
        PyArray2::from_vec2(py, &rows).expect("6x6")
    }

    /// Fraction of scene voxels with a same-class model voxel within one
    /// voxel under the transform.
    #[getter]
    fn overlap(&self) -> f32 {
        self.result.overlap
    }

    /// Agreement of what both maps saw standing (the verdict's measure).
    #[getter]
    fn agreement(&self) -> f32 {
        self.result.agreement
    }

    /// Inlier voxels.
    #[getter]
    fn inliers(&self) -> u32 {
        self.result.inliers
    }

    /// EM iterations.
    #[getter]
    fn iterations(&self) -> u32 {
        self.result.iterations
    }

    fn __repr__(&self) -> String {
        let t = self.result.transform.translation.vector;
        format!(
            "cosem.Match({}, t = ({:.3}, {:.3}, {:.3}) m, overlap {:.2})",
            self.result.status.as_str(),
            t.x,
            t.y,
            t.z,
            self.result.overlap
        )
    }
}

/// Aligns `scene` to `model`: `T_model_scene` from `init` (a 4x4 array),
/// or with no prior (`init=None`: every heading and offset searched).
/// `method` ("cosem", "cosem-hard", "geometric") and `dof` (6 or 4) as
/// the command line's; `em_iterations`, `min_overlap`, `min_agreement` and
/// `search_nodes` (None: the host pipeline's) through the pipeline's one
/// validator.
#[pyfunction(name = "match")]
#[pyo3(signature = (model, scene, init = None, method = "cosem", dof = 6, em_iterations = None, min_overlap = None, min_agreement = None, search_nodes = None))]
#[allow(clippy::too_many_arguments)]
fn match_maps(
    model: &Map,
    scene: &Map,
    init: Option<&Bound<'_, PyAny>>,
    method: &str,
    dof: u8,
    em_iterations: Option<f64>,
    min_overlap: Option<f64>,
    min_agreement: Option<f64>,
    search_nodes: Option<f64>,
) -> PyResult<Match> {
    use cosem_core::pipeline::{Pipeline, Setting};
    let method = cosem_core::matching::Method::from_name(method)
        .ok_or_else(|| value_error(format!("method {method:?}: expected cosem, cosem-hard or geometric")))?;
    let dof = cosem_core::matching::Dof::from_count(dof).ok_or_else(|| value_error(format!("dof {dof}: expected 6 or 4")))?;
    let tuned = [
        (Setting::Iterations, em_iterations),
        (Setting::MinOverlap, min_overlap),
        (Setting::MinAgreement, min_agreement),
        (Setting::SearchNodes, search_nodes),
    ];
    let mut pipeline = Pipeline::HOST;
    for (setting, value) in tuned {
        if let Some(v) = value {
            pipeline = pipeline.with(setting, v).map_err(value_error)?;
        }
    }
    let mut how = pipeline.alignment;
    how.settings = MatchSettings { method, dof, ..how.settings };
    if (model.map.resolution() - scene.map.resolution()).abs() > 1e-6 {
        return Err(value_error(format!(
            "resolutions differ: {} m and {} m",
            model.map.resolution(),
            scene.map.resolution()
        )));
    }
    let prior = match init {
        None => None,
        Some(obj) => {
            let a = float_array(obj, "init", "4x4")?;
            let a: PyReadonlyArray2<'_, f64> = a.extract()?;
            if a.shape() != [4, 4] {
                return Err(value_error(format!("init must be a 4x4 array, got shape {:?}", a.shape())));
            }
            let a = a.as_array();
            let m = nalgebra::Matrix4::from_fn(|r, c| a[[r, c]]);
            let iso = cosem_core::geometry::rigid_from_matrix(&m)
                .ok_or_else(|| value_error("init is not a rigid transform (its 3x3 part must be a rotation)"))?;
            Some(nalgebra::convert::<_, Isometry3<f32>>(iso))
        }
    };
    let pm = prepare(&model.map, DEFAULT_LEVELS).map_err(value_error)?;
    let ps = prepare(&scene.map, DEFAULT_LEVELS).map_err(value_error)?;
    let (result, _) = align(how, prior.as_ref(), (&pm, &ps)).map_err(value_error)?;
    Ok(Match { result })
}

#[pymodule]
fn cosem(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Map>()?;
    m.add_class::<Match>()?;
    m.add_function(wrap_pyfunction!(match_maps, m)?)?;
    let names: Vec<&str> = (0..19u8).filter_map(Class::from_index).map(Class::name).collect();
    m.add("CLASSES", names)?;
    Ok(())
}
