//! A user's class table: their segmentation's label ids mapped to cosem's
//! 19 classes (or to a subset of them), from a TOML file, for every reader
//! of scans (a SemanticKITTI-layout folder, PCD, PLY).
//!
//! ```toml
//! # label id (the low 16 bits of a point's label) = class name
//! [ids]
//! 0 = "unlabeled"   # never inserted into a map
//! 1 = "road"
//! 2 = "sidewalk"
//! 7 = "car"
//! ```
//!
//! Class names are the conventions' (`car, bicycle, ..., traffic-sign`);
//! `unlabeled` drops the points of an id. An id a scan holds but the table
//! does not name is an error naming the scan and the point, never a
//! silent guess.

use cosem_core::classes::Class;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Why a class table could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ClassTableError {
    /// Reading the file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Not a class table.
    #[error("{path}: {what}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong (with TOML's line and column where it knows them).
        what: String,
    },
}

impl crate::error::LayerError for ClassTableError {}

/// The file's shape.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    ids: BTreeMap<String, String>,
}

/// Label ids to classes (`None`: dropped).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ClassTable {
    ids: BTreeMap<u16, Option<Class>>,
}

impl ClassTable {
    /// Reads a table from a TOML file.
    pub fn read(path: &Path) -> Result<Self, ClassTableError> {
        let text = std::fs::read_to_string(path).map_err(|source| ClassTableError::Io { path: path.into(), source })?;
        Self::parse(&text).map_err(|what| ClassTableError::Invalid { path: path.into(), what })
    }

    /// Parses a table's text.
    pub fn parse(text: &str) -> Result<Self, String> {
        let file: File = toml::from_str(text).map_err(|e| e.to_string().trim_end().to_owned())?;
        let mut ids = BTreeMap::new();
        let mut keys: BTreeMap<u16, String> = BTreeMap::new();
        for (key, name) in file.ids {
            let id: u16 = key.trim().parse().map_err(|_| format!("[ids]: `{key}` is not a label id (0 to 65535)"))?;
            if let Some(first) = keys.insert(id, key.clone()) {
                return Err(format!("[ids]: `{first}` and `{key}` are both label id {id}: name each id once"));
            }
            let class = match name.as_str() {
                "unlabeled" => None,
                n => Some(Class::from_name(n).ok_or_else(|| {
                    let all: Vec<&str> = (0..19u8).filter_map(Class::from_index).map(Class::name).collect();
                    format!("[ids] {id}: `{n}` is not a class (one of unlabeled, {})", all.join(", "))
                })?),
            };
            ids.insert(id, class);
        }
        if ids.values().all(Option::is_none) {
            return Err("[ids]: no id maps to a class".into());
        }
        Ok(ClassTable { ids })
    }

    /// The class of a label word (its low 16 bits): `Ok(None)` for an id
    /// the table drops, `Err(id)` for one it does not name.
    pub fn class_of(&self, label: u32) -> Result<Option<Class>, u16> {
        let id = (label & 0xFFFF) as u16;
        self.ids.get(&id).copied().ok_or(id)
    }

    /// Rewrites the labels of `frames` as SemanticKITTI ids of their classes
    /// (0, unlabeled, for the ids the table drops), so that the rest of the
    /// pipeline reads them as a SemanticKITTI folder's. `Err((frame, point,
    /// id))` names the first point whose id the table does not name
    /// (`frame` is the frame's position in `frames`).
    pub fn relabel(&self, frames: &mut [crate::sources::kitti::Frame]) -> Result<(), (usize, usize, u16)> {
        for (f, frame) in frames.iter_mut().enumerate() {
            for (i, l) in frame.labels.iter_mut().enumerate() {
                let class = self.class_of(*l).map_err(|id| (f, i, id))?;
                *l = class.map_or(0, |c| u32::from(c.semantic_kitti_id()));
            }
        }
        Ok(())
    }

    /// The classes the table maps to.
    pub fn classes(&self) -> impl Iterator<Item = Class> + '_ {
        let mut seen = [false; 19];
        self.ids.values().flatten().copied().filter(move |c| !std::mem::replace(&mut seen[c.index() as usize], true))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_id_named_twice_is_refused() {
        let e = ClassTable::parse("[ids]\n40 = \"road\"\n\"040\" = \"car\"\n").unwrap_err();
        assert!(e.contains("`040` and `40`") || e.contains("`40` and `040`"), "{e}");
        assert!(e.contains("label id 40"), "{e}");
    }

    #[test]
    fn a_table_maps_names_and_drops_and_refuses_what_it_must() {
        let t = ClassTable::parse(
            "# mine\n[ids]\n0 = \"unlabeled\"\n1 = \"road\"\n7 = \"car\"\n\"30\" = \"traffic-sign\"\n",
        )
        .unwrap();
        assert_eq!(t.class_of(1), Ok(Some(Class::Road)));
        assert_eq!(t.class_of(0x0005_0007), Ok(Some(Class::Car)), "the low 16 bits");
        assert_eq!(t.class_of(30), Ok(Some(Class::TrafficSign)));
        assert_eq!(t.class_of(0), Ok(None));
        assert_eq!(t.class_of(2), Err(2));
        assert_eq!(t.classes().count(), 3);
        let e = ClassTable::parse("[ids]\n1 = \"roads\"\n").unwrap_err();
        assert!(e.contains("`roads` is not a class") && e.contains("traffic-sign"), "{e}");
        assert!(ClassTable::parse("[ids]\nx = \"road\"\n").unwrap_err().contains("not a label id"));
        assert!(ClassTable::parse("[ids]\n70000 = \"road\"\n").unwrap_err().contains("not a label id"));
        assert!(ClassTable::parse("[ids]\n0 = \"unlabeled\"\n").unwrap_err().contains("no id maps"));
        let e = ClassTable::parse("[ids]\n1 = road\n").unwrap_err();
        assert!(e.contains("line 2"), "{e}");
        assert!(ClassTable::parse("[classes]\n1 = \"road\"\n").is_err());
    }
}
