//! The driver wires each robot's ports in its peers' order and runs in
//! virtual time.

use super::*;
use crate::robot::{Machine, Meter, Poll, RobotError};
use embedded_io::{Read, ReadReady, Write, WriteReady};
use std::vec;

/// A robot that says its index on every port, once, and reports which
/// index it heard on each port (in port order), fed nothing.
struct Caller {
    me: u8,
    said: bool,
    heard: Vec<Option<u8>>,
}

impl<F: Write, L: Read + Write + ReadReady + WriteReady, T: Meter> Machine<F, L, T> for Caller {
    type Report = Vec<Option<u8>>;
    fn poll(&mut self, _feed: &mut F, ports: &mut [L], _now: u64, _m: &T) -> Result<Poll<Self::Report>, RobotError> {
        if !self.said {
            for p in ports.iter_mut() {
                p.write_all(&[self.me]).map_err(|_| RobotError::FeedIo)?;
            }
            self.heard = vec![None; ports.len()];
            self.said = true;
        }
        for (p, h) in ports.iter_mut().zip(&mut self.heard) {
            let mut b = [0u8; 1];
            if p.read_ready().map_err(|_| RobotError::FeedIo)? && p.read(&mut b).map_err(|_| RobotError::FeedIo)? == 1 {
                *h = Some(b[0]);
            }
        }
        Ok(if self.heard.iter().all(Option::is_some) { Poll::Done(self.heard.clone()) } else { Poll::Busy })
    }
}

#[test]
fn each_robot_hears_its_peers_in_index_order() {
    let mut robots: Vec<Caller> = (0..4).map(|me| Caller { me, said: false, heard: Vec::new() }).collect();
    let mut dyns: Vec<&mut SimRobot<'_, '_, Vec<Option<u8>>>> =
        robots.iter_mut().map(|r| r as &mut SimRobot<'_, '_, _>).collect();
    // The mesh listed backwards: ports still follow the peers' indices.
    let mut wires = Wire::mesh(4, 115_200);
    wires.reverse();
    let out = run(&mut dyns, &[], &wires, 100);
    for (me, ended) in out.iter().enumerate() {
        let expect: Vec<Option<u8>> = (0..4u8).filter(|&p| usize::from(p) != me).map(Some).collect();
        assert_eq!(ended.result, Some(Ok(expect)), "robot {me}");
        // One byte at 115200 baud crosses within the first milliseconds.
        assert!(ended.at_ms < 5, "robot {me} at {} ms", ended.at_ms);
    }
    // A line that moves nothing: both still busy at the limit.
    let (mut a, mut b) = (Caller { me: 0, said: false, heard: vec![] }, Caller { me: 1, said: false, heard: vec![] });
    let dead = Wire { a: 0, b: 1, line: SimConfig { bytes_per_ms: 0.0, ..SimConfig::clean(115_200, 1) } };
    let out = run(&mut [&mut a as &mut SimRobot<'_, '_, _>, &mut b], &[], &[dead], 20);
    assert!(out.iter().all(|o| o.result.is_none() && o.at_ms == 21));
}
