//! Serial ports for the link, whatever the board: a receive ring that an
//! interrupt handler fills, and one adapter from `embedded-hal-nb` serial
//! (what board HALs implement; embedded-hal 1.0 has no serial traits) to
//! the `embedded-io` traits the core's link and feed speak.
//!
//! A robot that prepares or matches for a second does not read its UARTs;
//! a real UART holds one byte and overruns at the next. So reception is
//! driven by the UART's receive interrupt ([`IrqReceiver`]): the handler
//! moves each byte into a [`RxRing`], the robot reads the ring when it
//! polls. The ring is sized above the link's window (the bytes a peer sends
//! before it waits for an acknowledgement), so it does not fill while the
//! robot is busy. Should it near full (a feeder that does not wait), the
//! handler stops listening and the byte stays in the UART until the robot
//! reads again: under QEMU the line then waits, on hardware the UART
//! overruns and the link's CRC and retransmission repair the loss.

use core::cell::{RefCell, UnsafeCell};
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use cortex_m::interrupt::Mutex;

/// A single-producer (interrupt handler), single-consumer (main loop)
/// ring of received bytes. `N` must be a power of two. Only its
/// [`IrqReceiver`] pushes and pops, each inside a critical section, so no
/// second producer or consumer can exist in safe code; what others see are
/// its counters.
pub struct RxRing<const N: usize> {
    buf: UnsafeCell<[u8; N]>,
    /// Bytes pushed (written by the producer only).
    head: AtomicU32,
    /// Bytes popped (written by the consumer only).
    tail: AtomicU32,
    dropped: AtomicU32,
    high_water: AtomicU32,
}

// SAFETY: `push` and `pop_into` are private, and their one caller
// (`IrqReceiver`) runs each in a critical section: one producer writes
// `buf[head]` then publishes `head` (Release); one consumer reads
// `buf[tail]` after loading `head` (Acquire) and then publishes `tail`. A
// slot is never written and read at once. Shared references reach only the
// counters (atomics).
unsafe impl<const N: usize> Sync for RxRing<N> {}

impl<const N: usize> RxRing<N> {
    const MASK: u32 = {
        assert!(N.is_power_of_two() && N <= 1 << 16, "ring size: a power of two up to 64 KiB");
        N as u32 - 1
    };

    /// An empty ring.
    pub const fn new() -> Self {
        RxRing {
            buf: UnsafeCell::new([0; N]),
            head: AtomicU32::new(0),
            tail: AtomicU32::new(0),
            dropped: AtomicU32::new(0),
            high_water: AtomicU32::new(0),
        }
    }

    /// Producer (the interrupt handler, in a critical section): appends a
    /// byte, or counts it dropped when the ring is full.
    fn push(&self, byte: u8) {
        let head = self.head.load(Ordering::Relaxed);
        let tail = self.tail.load(Ordering::Acquire);
        let used = head.wrapping_sub(tail);
        if used as usize >= N {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        // SAFETY: the slot at `head` is free (used < N) and only the
        // producer writes; the consumer reads it only after `head` moves.
        unsafe { (*self.buf.get())[(head & Self::MASK) as usize] = byte };
        self.head.store(head.wrapping_add(1), Ordering::Release);
        if used + 1 > self.high_water.load(Ordering::Relaxed) {
            self.high_water.store(used + 1, Ordering::Relaxed);
        }
    }

    /// Consumer: bytes waiting.
    pub fn len(&self) -> usize {
        self.head.load(Ordering::Acquire).wrapping_sub(self.tail.load(Ordering::Relaxed)) as usize
    }

    /// Consumer: whether no byte waits.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Consumer (in a critical section): moves waiting bytes into `out`;
    /// returns how many.
    fn pop_into(&self, out: &mut [u8]) -> usize {
        let head = self.head.load(Ordering::Acquire);
        let mut tail = self.tail.load(Ordering::Relaxed);
        let mut n = 0;
        for slot in out.iter_mut() {
            if tail == head {
                break;
            }
            // SAFETY: the slot at `tail` was published by the producer
            // (tail != head) and is not written again until `tail` moves.
            *slot = unsafe { (*self.buf.get())[(tail & Self::MASK) as usize] };
            tail = tail.wrapping_add(1);
            n += 1;
        }
        self.tail.store(tail, Ordering::Release);
        n
    }

    /// Bytes the ring ever took (wrapping).
    pub fn pushed(&self) -> u32 {
        self.head.load(Ordering::Acquire)
    }

    /// Bytes lost because the ring was full.
    pub fn dropped(&self) -> u32 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Most bytes the ring ever held at once.
    pub fn high_water(&self) -> u32 {
        self.high_water.load(Ordering::Relaxed)
    }
}

impl<const N: usize> Default for RxRing<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// A UART receiver whose receive interrupt can be switched: what a board
/// adds to its HAL's `embedded-hal-nb` reader (embedded-hal has no
/// interrupt traits).
pub trait RxInterrupt: embedded_hal_nb::serial::Read<u8> {
    /// Raise the interrupt when a byte arrives (once, at start).
    fn listen(&mut self);
    /// Acknowledge the interrupt before draining (a byte arriving while
    /// the handler drains raises it again). Nothing by default: many UARTs
    /// clear it by the read itself.
    fn acknowledge(&mut self) {}
    /// Hold the interrupt off while the ring is full (e.g. mask it in the
    /// NVIC: a UART's interrupt line stays raised while a byte waits in it,
    /// so switching the UART's own enable may not lower it).
    fn pause(&mut self);
    /// Let it through again.
    fn resume(&mut self);
}

/// A receiver driven by its interrupt: the handler calls
/// [`IrqReceiver::on_interrupt`], the main loop reads the ring.
pub struct IrqReceiver<R, const N: usize> {
    rx: Mutex<RefCell<Option<R>>>,
    ring: RxRing<N>,
    paused: AtomicBool,
    errors: AtomicU32,
}

impl<R: RxInterrupt, const N: usize> IrqReceiver<R, N> {
    /// Nothing installed yet.
    pub const fn new() -> Self {
        IrqReceiver {
            rx: Mutex::new(RefCell::new(None)),
            ring: RxRing::new(),
            paused: AtomicBool::new(false),
            errors: AtomicU32::new(0),
        }
    }

    /// Takes the receiver and starts listening (the board unmasks the
    /// interrupt in the NVIC).
    pub fn install(&self, mut rx: R) {
        rx.listen();
        cortex_m::interrupt::free(|cs| *self.rx.borrow(cs).borrow_mut() = Some(rx));
    }

    /// The interrupt handler's work: every byte the UART holds into the
    /// ring; when the ring is nearly full, stop listening (the byte waits
    /// in the UART).
    pub fn on_interrupt(&self) {
        cortex_m::interrupt::free(|cs| {
            let mut cell = self.rx.borrow(cs).borrow_mut();
            let Some(rx) = cell.as_mut() else { return };
            rx.acknowledge();
            while self.ring.len() < N - 1 {
                match rx.read() {
                    Ok(b) => self.ring.push(b),
                    Err(nb::Error::WouldBlock) => return,
                    Err(nb::Error::Other(_)) => {
                        self.errors.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
            rx.pause();
            self.paused.store(true, Ordering::Release);
        });
    }

    /// Main loop: moves waiting bytes into `out`, and listens again once
    /// there is room.
    pub fn read(&self, out: &mut [u8]) -> usize {
        // One consumer at a time, whoever calls (the ring's tail is not
        // shared between readers).
        let n = cortex_m::interrupt::free(|_| self.ring.pop_into(out));
        if self.paused.load(Ordering::Acquire) && self.ring.len() < N / 2 {
            cortex_m::interrupt::free(|cs| {
                if let Some(rx) = self.rx.borrow(cs).borrow_mut().as_mut() {
                    self.paused.store(false, Ordering::Release);
                    rx.resume();
                }
            });
        }
        n
    }

    /// The ring (its counters: [`RxRing::len`], [`RxRing::pushed`],
    /// [`RxRing::dropped`], [`RxRing::high_water`]).
    pub fn ring(&self) -> &RxRing<N> {
        &self.ring
    }

    /// Reception errors the UART reported (overrun, framing, noise).
    pub fn errors(&self) -> u32 {
        self.errors.load(Ordering::Relaxed)
    }
}

impl<R: RxInterrupt, const N: usize> Default for IrqReceiver<R, N> {
    fn default() -> Self {
        Self::new()
    }
}

/// Bytes each receive ring holds: above the link's window (1,792 stream
/// bytes in flight, in frames of a few percent overhead) with room for the
/// peer's resends while the robot is busy.
pub const RX_RING: usize = 4096;

/// A serial port for the link and the feed: bytes received by interrupt
/// into a ring ([`IrqReceiver`]), sent through any `embedded-hal-nb` serial
/// transmitter. The one adapter from embedded-hal-nb to embedded-io: any
/// HAL whose UART implements `embedded_hal_nb::serial::{Read, Write}` drops
/// in.
pub struct RingSerial<'r, R, T, const N: usize> {
    rx: &'r IrqReceiver<R, N>,
    tx: T,
    /// Called, interrupts masked, while waiting for a byte with none
    /// there (e.g. `wfi`: the next interrupt wakes it).
    idle: fn(),
}

impl<'r, R: RxInterrupt, T, const N: usize> RingSerial<'r, R, T, N> {
    /// A port over a receiver its interrupt drives and a transmitter.
    pub fn new(rx: &'r IrqReceiver<R, N>, tx: T, idle: fn()) -> Self {
        RingSerial { rx, tx, idle }
    }

    /// The receiver (its counters).
    pub fn receiver(&self) -> &'r IrqReceiver<R, N> {
        self.rx
    }
}

/// What went wrong on a serial port (only the transmitter can fail: a
/// lost byte on reception shows in [`RxRing::dropped`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SerialError(pub embedded_io::ErrorKind);

impl embedded_io::Error for SerialError {
    fn kind(&self) -> embedded_io::ErrorKind {
        self.0
    }
}

fn nb_error<E: embedded_hal_nb::serial::Error>(e: E) -> SerialError {
    use embedded_hal_nb::serial::ErrorKind as K;
    SerialError(match e.kind() {
        K::Overrun | K::FrameFormat | K::Parity | K::Noise => embedded_io::ErrorKind::InvalidData,
        _ => embedded_io::ErrorKind::Other,
    })
}

impl<R, T: embedded_hal_nb::serial::ErrorType, const N: usize> embedded_io::ErrorType for RingSerial<'_, R, T, N> {
    type Error = SerialError;
}

impl<R, T: embedded_hal_nb::serial::Write<u8>, const N: usize> embedded_io::Write for RingSerial<'_, R, T, N> {
    /// Blocks until the first byte is taken, then sends what goes without
    /// waiting.
    fn write(&mut self, buf: &[u8]) -> Result<usize, SerialError> {
        let mut n = 0;
        for &b in buf {
            match self.tx.write(b) {
                Ok(()) => n += 1,
                Err(nb::Error::WouldBlock) if n > 0 => break,
                Err(nb::Error::WouldBlock) => {
                    nb::block!(self.tx.write(b)).map_err(nb_error)?;
                    n += 1;
                }
                Err(nb::Error::Other(e)) => return Err(nb_error(e)),
            }
        }
        Ok(n)
    }

    fn flush(&mut self) -> Result<(), SerialError> {
        nb::block!(self.tx.flush()).map_err(nb_error)
    }
}

impl<R, T: embedded_hal_nb::serial::Write<u8>, const N: usize> embedded_io::WriteReady for RingSerial<'_, R, T, N> {
    /// Whether the transmitter is done with what it was given (so a write
    /// of one byte does not wait).
    fn write_ready(&mut self) -> Result<bool, SerialError> {
        match self.tx.flush() {
            Ok(()) => Ok(true),
            Err(nb::Error::WouldBlock) => Ok(false),
            Err(nb::Error::Other(e)) => Err(nb_error(e)),
        }
    }
}

impl<R: RxInterrupt, T: embedded_hal_nb::serial::ErrorType, const N: usize> embedded_io::ReadReady
    for RingSerial<'_, R, T, N>
{
    fn read_ready(&mut self) -> Result<bool, SerialError> {
        // A paused receiver listens again once the ring has room.
        self.rx.read(&mut []);
        Ok(!self.rx.ring().is_empty())
    }
}

impl<R: RxInterrupt, T: embedded_hal_nb::serial::ErrorType, const N: usize> embedded_io::Read
    for RingSerial<'_, R, T, N>
{
    /// Waits (idling) until a byte is there, then returns what is there.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, SerialError> {
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            let n = self.rx.read(buf);
            if n > 0 {
                return Ok(n);
            }
            // Masked, so a byte that arrives now still wakes the idle.
            cortex_m::interrupt::free(|_| {
                if self.rx.ring().is_empty() {
                    (self.idle)();
                }
            });
        }
    }
}
