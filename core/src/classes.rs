//! Layer 1: the class table, SemanticKITTI's standard learning map (19
//! classes).
//!
//! Raw SemanticKITTI ids are mapped with [`Class::from_semantic_kitti`]. Ids the
//! standard map sends to "unlabeled" (0 unlabeled, 1 outlier, 52 other-structure,
//! 99 other-object) never enter a map; moving objects (ids 252 and above) are
//! skipped by default or mapped to their static class on request.

use serde::{Deserialize, Serialize};

/// Number of classes in the table.
pub const NUM_CLASSES: usize = 19;

/// Version of the class table; carried in map files and on the wire so that
/// two robots with different tables notice it.
pub const CLASS_TABLE_VERSION: u16 = 1;

/// One semantic class of the table. The discriminant is the class index.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
#[allow(missing_docs)]
pub enum Class {
    Car = 0,
    Bicycle = 1,
    Motorcycle = 2,
    Truck = 3,
    OtherVehicle = 4,
    Person = 5,
    Bicyclist = 6,
    Motorcyclist = 7,
    Road = 8,
    Parking = 9,
    Sidewalk = 10,
    OtherGround = 11,
    Building = 12,
    Fence = 13,
    Vegetation = 14,
    Trunk = 15,
    Terrain = 16,
    Pole = 17,
    TrafficSign = 18,
}

/// What to do with SemanticKITTI's moving-object ids (252 and above).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MovingObjects {
    /// Leave them out of the map (default): they are not where they were.
    #[default]
    Skip,
    /// Map them to their static class (moving-car to car, ...).
    AsStatic,
}

const NAMES: [&str; NUM_CLASSES] = [
    "car",
    "bicycle",
    "motorcycle",
    "truck",
    "other-vehicle",
    "person",
    "bicyclist",
    "motorcyclist",
    "road",
    "parking",
    "sidewalk",
    "other-ground",
    "building",
    "fence",
    "vegetation",
    "trunk",
    "terrain",
    "pole",
    "traffic-sign",
];

/// SemanticKITTI colours (RGB) of each class, as in its `semantic-kitti.yaml`.
const COLORS: [[u8; 3]; NUM_CLASSES] = [
    [100, 150, 245],
    [100, 230, 245],
    [30, 60, 150],
    [80, 30, 180],
    [0, 0, 255],
    [255, 30, 30],
    [255, 40, 200],
    [150, 30, 90],
    [255, 0, 255],
    [255, 150, 255],
    [75, 0, 75],
    [175, 0, 75],
    [255, 200, 0],
    [255, 120, 50],
    [0, 175, 0],
    [135, 60, 0],
    [150, 240, 80],
    [255, 240, 150],
    [255, 0, 0],
];

/// The raw SemanticKITTI id each class is written back as.
const RAW_IDS: [u16; NUM_CLASSES] = [10, 11, 15, 18, 20, 30, 31, 32, 40, 44, 48, 49, 50, 51, 70, 71, 72, 80, 81];

impl Class {
    /// All classes in index order.
    pub const ALL: [Class; NUM_CLASSES] = [
        Class::Car,
        Class::Bicycle,
        Class::Motorcycle,
        Class::Truck,
        Class::OtherVehicle,
        Class::Person,
        Class::Bicyclist,
        Class::Motorcyclist,
        Class::Road,
        Class::Parking,
        Class::Sidewalk,
        Class::OtherGround,
        Class::Building,
        Class::Fence,
        Class::Vegetation,
        Class::Trunk,
        Class::Terrain,
        Class::Pole,
        Class::TrafficSign,
    ];

    /// The class with this index (0..19), if any.
    pub fn from_index(index: u8) -> Option<Class> {
        Class::ALL.get(usize::from(index)).copied()
    }

    /// Index of the class in the table (0..19).
    pub const fn index(self) -> u8 {
        self as u8
    }

    /// The conventions' name, e.g. `"traffic-sign"`.
    pub fn name(self) -> &'static str {
        NAMES[self as usize]
    }

    /// The class with this conventions' name, if any.
    pub fn from_name(name: &str) -> Option<Class> {
        NAMES.iter().position(|n| *n == name).and_then(|i| Class::from_index(i as u8))
    }

    /// SemanticKITTI colour (RGB).
    pub fn color(self) -> [u8; 3] {
        COLORS[self as usize]
    }

    /// The raw SemanticKITTI id that stands for this class when writing labels.
    pub fn semantic_kitti_id(self) -> u16 {
        RAW_IDS[self as usize]
    }

    /// Whether the low 16 bits of a label word are an id of SemanticKITTI's
    /// label set (0 unlabeled, 1 outlier, 10-81 static, 99, 252-259 moving):
    /// anything else is a corrupted or foreign label file.
    pub fn is_semantic_kitti_id(raw: u32) -> bool {
        matches!(
            raw & 0xFFFF,
            0 | 1
                | 10
                | 11
                | 13
                | 15
                | 16
                | 18
                | 20
                | 30
                | 31
                | 32
                | 40
                | 44
                | 48
                | 49
                | 50
                | 51
                | 52
                | 60
                | 70
                | 71
                | 72
                | 80
                | 81
                | 99
                | 252..=259
        )
    }

    /// Maps a raw SemanticKITTI label (the low 16 bits of a `.label` entry; the
    /// instance id in the high bits is ignored) through the standard learning map.
    /// `None`: the point carries no usable class and stays out of the map.
    pub fn from_semantic_kitti(raw: u32, moving: MovingObjects) -> Option<Class> {
        let id = raw & 0xFFFF;
        let static_id = if id >= 252 {
            match moving {
                MovingObjects::Skip => return None,
                MovingObjects::AsStatic => match id {
                    252 => 10,
                    253 => 31,
                    254 => 30,
                    255 => 32,
                    256 => 16,
                    257 => 13,
                    258 => 18,
                    259 => 20,
                    _ => return None,
                },
            }
        } else {
            id
        };
        Some(match static_id {
            10 => Class::Car,
            11 => Class::Bicycle,
            13 | 16 | 20 => Class::OtherVehicle,
            15 => Class::Motorcycle,
            18 => Class::Truck,
            30 => Class::Person,
            31 => Class::Bicyclist,
            32 => Class::Motorcyclist,
            40 | 60 => Class::Road,
            44 => Class::Parking,
            48 => Class::Sidewalk,
            49 => Class::OtherGround,
            50 => Class::Building,
            51 => Class::Fence,
            70 => Class::Vegetation,
            71 => Class::Trunk,
            72 => Class::Terrain,
            80 => Class::Pole,
            81 => Class::TrafficSign,
            _ => return None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_indices_are_dense() {
        for (i, c) in Class::ALL.iter().enumerate() {
            assert_eq!(c.index() as usize, i);
            assert_eq!(Class::from_name(c.name()), Some(*c));
            assert_eq!(Class::from_semantic_kitti(c.semantic_kitti_id() as u32, MovingObjects::Skip), Some(*c));
        }
        assert_eq!(Class::from_index(19), None);
    }

    #[test]
    fn standard_learning_map() {
        let skip = MovingObjects::Skip;
        for ignored in [0u32, 1, 52, 99, 252, 259, 1000] {
            assert_eq!(Class::from_semantic_kitti(ignored, skip), None, "{ignored}");
        }
        assert_eq!(Class::from_semantic_kitti(13, skip), Some(Class::OtherVehicle));
        assert_eq!(Class::from_semantic_kitti(16, skip), Some(Class::OtherVehicle));
        assert_eq!(Class::from_semantic_kitti(60, skip), Some(Class::Road));
        // Instance ids live in the high 16 bits.
        assert_eq!(Class::from_semantic_kitti((7 << 16) | 10, skip), Some(Class::Car));
        let keep = MovingObjects::AsStatic;
        assert_eq!(Class::from_semantic_kitti(252, keep), Some(Class::Car));
        assert_eq!(Class::from_semantic_kitti(254, keep), Some(Class::Person));
        assert_eq!(Class::from_semantic_kitti(257, keep), Some(Class::OtherVehicle));
        assert_eq!(Class::from_semantic_kitti(258, keep), Some(Class::Truck));
    }
}
