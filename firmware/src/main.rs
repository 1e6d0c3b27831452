//! cosem firmware (for now): builds a small semantic map on the target with
//! the core's code and reports it over semihosting. The robot's full loop
//! (feed, map, exchange, match, report) grows here.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use panic_halt as _;

use cosem_core::classes::Class;
use cosem_core::map::{ArrayStorage, FixedMap, MapConfig};

/// Voxels of the on-board map for this smoke run.
const CAPACITY: usize = 512;

#[entry]
fn main() -> ! {
    let ok = run().is_ok();
    debug::exit(if ok { debug::EXIT_SUCCESS } else { debug::EXIT_FAILURE });
    loop {}
}

fn run() -> Result<(), ()> {
    let mut map = FixedMap::<CAPACITY>::new(ArrayStorage::new(), MapConfig::default()).map_err(|_| ())?;
    // A pole and a strip of road, as a LiDAR would see them.
    for i in 0..40u16 {
        let z = f32::from(i) * 0.1;
        map.insert_point([5.05, 2.05, z], Class::Pole).map_err(|_| ())?;
        map.insert_point([f32::from(i) * 0.2, 0.1, -1.7], Class::Road).map_err(|_| ())?;
    }
    let poles = map.iter().filter(|v| v.class() == Some(Class::Pole)).count();
    hprintln!("cosem-firmware: {} voxels, {} pole voxels", map.len(), poles);
    if map.len() == 60 && poles == 20 {
        Ok(())
    } else {
        Err(())
    }
}
