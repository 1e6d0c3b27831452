//! The boards a robot runs on under QEMU (`cosem robots --board-a/-b`):
//! which emulated machine, which firmware binary, which UART is the feeder
//! line and which the link, and what a robot on it can hold. Also the
//! static RAM a firmware image takes, read from its ELF section headers.

use crate::error::Error;
use cosem_core::pipeline::Pipeline;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

/// A board for one robot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Board {
    /// QEMU `mps2-an386` (Cortex-M4F, 1 MiB budget): the full robot, both
    /// maps and the matcher.
    Mps2An386,
    /// An STM32F405 (QEMU `netduinoplus2`: 128 KiB SRAM + 64 KiB CCM,
    /// through stm32f4xx-hal): the matching robot in 192 KiB, with fewer
    /// voxels of 0.7 m (`Capacity::STM32F405`).
    Stm32f405,
    /// The same chip as a sender: it maps and sends, and is told the
    /// result (a one-sided exchange).
    Stm32f405Sender,
}

impl std::str::FromStr for Board {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "mps2-an386" => Ok(Board::Mps2An386),
            "stm32f405" => Ok(Board::Stm32f405),
            "stm32f405-sender" => Ok(Board::Stm32f405Sender),
            _ => Err(format!("unknown board `{s}`: mps2-an386, stm32f405 or stm32f405-sender")),
        }
    }
}

impl Board {
    /// Its name on the command line and in JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            Board::Mps2An386 => "mps2-an386",
            Board::Stm32f405 => "stm32f405",
            Board::Stm32f405Sender => "stm32f405-sender",
        }
    }

    /// Where `cargo build --release` in firmware/ puts its robot binary.
    pub fn default_firmware(self) -> &'static str {
        match self {
            Board::Mps2An386 => "firmware/target/thumbv7em-none-eabihf/release/robot",
            Board::Stm32f405 => "firmware/target/thumbv7em-none-eabihf/release/stm32f405-robot",
            Board::Stm32f405Sender => "firmware/target/thumbv7em-none-eabihf/release/stm32f405-sender",
        }
    }

    /// Whether its robot holds the peer's map and matches (else it sends
    /// its own and is told the result).
    pub fn matches(self) -> bool {
        self != Board::Stm32f405Sender
    }

    /// Its robot's capacities (the sizes of the memory its firmware
    /// declares).
    pub fn capacity(self) -> cosem_core::robot::Capacity {
        match self {
            Board::Mps2An386 => cosem_core::robot::Capacity::BOARD,
            Board::Stm32f405 => cosem_core::robot::Capacity::STM32F405,
            Board::Stm32f405Sender => cosem_core::robot::Capacity::sender(cosem_core::robot::SMALL_VOXELS),
        }
    }

    /// The capacities of its team robot (`cosem team --on-board`).
    pub fn team_capacity(self) -> cosem_core::robot::Capacity {
        match self {
            Board::Stm32f405 | Board::Stm32f405Sender => cosem_core::robot::Capacity::STM32F405_TEAM,
            Board::Mps2An386 => cosem_core::robot::Capacity::BOARD,
        }
    }

    /// The voxel size (m) its team robot maps at by default: its capacity's
    /// voxels hold a few scans' 25 m without eviction (the STM32F405
    /// team robot's 1,760 at 1 m; at 0.7 m they kept a 15 m radius).
    pub fn default_team_voxel(self) -> f32 {
        match self {
            Board::Stm32f405 | Board::Stm32f405Sender => Pipeline::STM32F405_TEAM.voxel,
            Board::Mps2An386 => Pipeline::MPS2.voxel,
        }
    }

    /// Where `cargo build --release` in firmware/ puts its team binary.
    pub fn team_firmware(self) -> &'static str {
        match self {
            Board::Stm32f405 | Board::Stm32f405Sender => "firmware/target/thumbv7em-none-eabihf/release/stm32f405-team",
            Board::Mps2An386 => "firmware/target/thumbv7em-none-eabihf/release/team",
        }
    }

    /// Its team robot's serial ports, in QEMU's order: the feeder's and
    /// the peers' (in peer index order). The mps2 board's feeder is UART1,
    /// its peers UART0, 2, 3, 4; the STM32F405's feeder USART1, its peers
    /// USART2 and USART3.
    pub fn team_ports(self) -> (usize, &'static [usize]) {
        match self {
            Board::Stm32f405 | Board::Stm32f405Sender => (0, &[1, 2]),
            Board::Mps2An386 => (1, &[0, 2, 3, 4]),
        }
    }

    /// Voxels its robot's map holds.
    pub fn voxels(self) -> usize {
        self.capacity().voxels
    }

    /// The voxel size (m) its robot maps at by default: its capacity's
    /// voxels cover a sensor's 25 m (the mps2 robot's 8,192 at 0.5 m, the
    /// STM32F405's 3,008 at 0.7 m).
    pub fn default_voxel(self) -> f32 {
        match self {
            Board::Stm32f405 => Pipeline::STM32F405.voxel,
            Board::Mps2An386 | Board::Stm32f405Sender => Pipeline::MPS2.voxel,
        }
    }

    /// The board's QEMU command line (`firmware/qemu/`: the one place it
    /// is written) with `serials` as its serial ports in order (`None`:
    /// `null`), the debugging options of [`debug_args`] and
    /// `elf` as the kernel.
    pub fn qemu_command(self, elf: &Path, serials: &[Option<u16>]) -> Command {
        let machine = match self {
            Board::Mps2An386 => include_str!("../../../firmware/qemu/mps2-an386.args"),
            Board::Stm32f405 | Board::Stm32f405Sender => include_str!("../../../firmware/qemu/stm32f405.args"),
        };
        let mut cmd = Command::new("qemu-system-arm");
        cmd.args(machine.split_whitespace())
            .args(include_str!("../../../firmware/qemu/common.args").split_whitespace())
            .args(serials.iter().flat_map(|p| {
                ["-serial".to_string(), p.map_or_else(|| "null".to_string(), |p| format!("tcp:127.0.0.1:{p}"))]
            }))
            .args(debug_args())
            .arg("-kernel")
            .arg(elf);
        cmd
    }

    /// Starts QEMU with `elf`, its feeder line and its link on TCP ports of
    /// this host (QEMU connects). The mps2 robot's link is UART0 and its
    /// feeder UART1; the STM32F405's feeder is USART1 (QEMU's first serial
    /// port) and its link USART2.
    pub fn qemu(self, elf: &Path, feed: u16, link: u16) -> std::io::Result<Child> {
        let serials = match self {
            Board::Mps2An386 => [Some(link), Some(feed)],
            Board::Stm32f405 | Board::Stm32f405Sender => [Some(feed), Some(link)],
        };
        self.qemu_command(elf, &serials).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::null()).spawn()
    }
}

/// Bytes of RAM a firmware image takes statically: every section that is
/// allocated and writable (`.data`, `.bss`, `.uninit`, a board's own RAM
/// sections), from the ELF's section headers. The stack comes on top.
pub fn static_ram_bytes(elf: &Path) -> Result<u64, Error> {
    let bytes = std::fs::read(elf).map_err(|source| Error::Io { path: elf.to_path_buf(), source })?;
    let bad = |what: &str| Error::Invalid(format!("{}: not a 32-bit little-endian ELF ({what})", elf.display()));
    let u16_at = |at: usize| bytes.get(at..at + 2).map(|b| u16::from_le_bytes([b[0], b[1]]));
    let u32_at = |at: usize| bytes.get(at..at + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    if bytes.get(..6) != Some(&[0x7F, b'E', b'L', b'F', 1, 1][..]) {
        return Err(bad("header"));
    }
    let shoff = u32_at(0x20).ok_or_else(|| bad("section table offset"))? as usize;
    let shentsize = usize::from(u16_at(0x2E).ok_or_else(|| bad("section entry size"))?);
    let shnum = usize::from(u16_at(0x30).ok_or_else(|| bad("section count"))?);
    if shentsize < 40 {
        return Err(bad("section entry size"));
    }
    const SHF_WRITE: u32 = 0x1;
    const SHF_ALLOC: u32 = 0x2;
    let mut total = 0u64;
    for k in 0..shnum {
        let at = shoff + k * shentsize;
        let flags = u32_at(at + 8).ok_or_else(|| bad("section header"))?;
        let size = u32_at(at + 20).ok_or_else(|| bad("section header"))?;
        if flags & (SHF_WRITE | SHF_ALLOC) == SHF_WRITE | SHF_ALLOC {
            total += u64::from(size);
        }
    }
    Ok(total)
}

/// The firmware for `board`: `given` if any, else its default binary.
pub fn firmware_for(board: Board, given: Option<&Path>) -> PathBuf {
    given.map_or_else(|| PathBuf::from(board.default_firmware()), Path::to_path_buf)
}

/// Extra QEMU arguments from the environment: a GDB port per instance
/// (`COSEM_DEBUG_GDB`), a TCG plugin (`COSEM_QEMU_PLUGIN`).
fn debug_args() -> Vec<String> {
    static NEXT: std::sync::atomic::AtomicU16 = std::sync::atomic::AtomicU16::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut args = match std::env::var("COSEM_DEBUG_GDB").ok().and_then(|v| v.parse::<u16>().ok()) {
        Some(base) => vec!["-gdb".into(), format!("tcp::{}", base + n)],
        None => vec![],
    };
    // A TCG plugin for every QEMU (e.g. a profiler); `{n}` becomes the
    // instance's number, so each writes its own file.
    if let Ok(plugin) = std::env::var("COSEM_QEMU_PLUGIN") {
        args.extend(["-plugin".into(), plugin.replace("{n}", &n.to_string())]);
    }
    args
}
