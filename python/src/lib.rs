//! Python bindings of cosem: semantic voxel maps and their alignment,
//! linking the core directly (no call to the `cosem` binary).
//!
//! ```python
//! import cosem
//! a, b = cosem.Map.load("a.cmap"), cosem.Map.load("b.cmap")
//! r = cosem.match(a, b)          # no prior; or init=4x4 T_model_scene
//! print(r.status, r.transform)   # "Converged", 4x4 numpy array
//! ```

use cosem_core::classes::{Class, MovingObjects};
use cosem_core::geometry::Isometry3;
use cosem_core::map::{Insertion, MapConfig};
use cosem_core::matching::{MatchResult, MatchSettings};
use cosem_host::align::{align, prepare, DEFAULT_LEVELS};
use cosem_host::mapping::HostMap;
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
        let (_, map) = cosem_host::cmap::read(&path).map_err(|e| PyIOError::new_err(e.to_string()))?;
        Ok(Map { map })
    }

    /// Writes the map as a `.cmap` file.
    fn save(&self, path: std::path::PathBuf) -> PyResult<()> {
        cosem_host::cmap::write(&path, &self.map, None, Some("cosem python"))
            .map(|_| ())
            .map_err(|e| PyIOError::new_err(e.to_string()))
    }

    /// A map of labelled points: `xyz` an (N, 3) float array in the map's
    /// frame (m), `labels` N SemanticKITTI ids (the low 16 bits of each),
    /// voxels of `voxel` metres. Points without a class (unlabeled,
    /// outliers, moving objects) are left out; NaN points are an error.
    #[staticmethod]
    #[pyo3(signature = (xyz, labels, voxel = 0.2))]
    fn from_points(xyz: PyReadonlyArray2<'_, f64>, labels: PyReadonlyArray1<'_, i64>, voxel: f32) -> PyResult<Self> {
        let shape = xyz.shape();
        if shape.len() != 2 || shape[1] != 3 {
            return Err(value_error(format!("xyz must be (N, 3), got {shape:?}")));
        }
        let (xyz, labels) = (xyz.as_array(), labels.as_array());
        if labels.len() != shape[0] {
            return Err(value_error(format!("{} points but {} labels", shape[0], labels.len())));
        }
        let config = MapConfig { resolution: voxel, ..MapConfig::default() };
        let mut map = cosem_core::map::vec_map(shape[0].max(1), config).map_err(value_error)?;
        for (i, (p, &l)) in xyz.outer_iter().zip(labels.iter()).enumerate() {
            let Some(class) = u32::try_from(l).ok().and_then(|l| Class::from_semantic_kitti(l, MovingObjects::Skip))
            else {
                continue;
            };
            let point = [p[0] as f32, p[1] as f32, p[2] as f32];
            match map.insert_point(point, class) {
                Ok(Insertion::Dropped) | Ok(_) => {}
                Err(e) => return Err(value_error(format!("point {i} {point:?}: {e}"))),
            }
        }
        Ok(Map { map })
    }

    /// The voxels: their mean positions as an (N, 3) float32 array and
    /// their classes as N uint8 class indices (255 without one; the names
    /// are `cosem.CLASSES`).
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
#[pyfunction(name = "match")]
#[pyo3(signature = (model, scene, init = None))]
fn match_maps(model: &Map, scene: &Map, init: Option<PyReadonlyArray2<'_, f64>>) -> PyResult<Match> {
    if (model.map.resolution() - scene.map.resolution()).abs() > 1e-6 {
        return Err(value_error(format!(
            "resolutions differ: {} m and {} m",
            model.map.resolution(),
            scene.map.resolution()
        )));
    }
    let prior = match init {
        None => None,
        Some(a) => {
            if a.shape() != [4, 4] {
                return Err(value_error(format!("init must be 4x4, got {:?}", a.shape())));
            }
            let a = a.as_array();
            let m = nalgebra::Matrix4::from_fn(|r, c| a[[r, c]]);
            let iso = cosem_core::geometry::rigid_from_matrix(&m)
                .ok_or_else(|| value_error("init is not a rigid transform"))?;
            Some(nalgebra::convert::<_, Isometry3<f32>>(iso))
        }
    };
    let pm = prepare(&model.map, DEFAULT_LEVELS).map_err(value_error)?;
    let ps = prepare(&scene.map, DEFAULT_LEVELS).map_err(value_error)?;
    let (result, _) = align(MatchSettings::default(), prior.as_ref(), (&pm, &ps)).map_err(value_error)?;
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
