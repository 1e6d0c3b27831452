//! Byte streams for `cosem link`: TCP and serial ports, behind the
//! `embedded-io` traits the core's link speaks (the firmware's UART driver
//! implements the same ones).

use cosem_core::link::Clock;
use std::io::{Read as _, Write as _};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

/// An I/O error of a transport.
#[derive(Debug)]
pub struct TransportError(pub std::io::Error);

impl embedded_io::Error for TransportError {
    fn kind(&self) -> embedded_io::ErrorKind {
        use embedded_io::ErrorKind as K;
        use std::io::ErrorKind as S;
        match self.0.kind() {
            S::UnexpectedEof | S::BrokenPipe => K::BrokenPipe,
            S::ConnectionReset => K::ConnectionReset,
            S::ConnectionAborted => K::ConnectionAborted,
            S::NotConnected => K::NotConnected,
            S::TimedOut => K::TimedOut,
            S::Interrupted => K::Interrupted,
            _ => K::Other,
        }
    }
}

/// Accepts one connection on `listener` before `deadline` (blocking, no
/// Nagle delay); a `TimedOut` error saying how long it waited otherwise.
pub fn accept_within(listener: &TcpListener, deadline: Instant) -> std::io::Result<TcpStream> {
    listener.set_nonblocking(true)?;
    let start = Instant::now();
    loop {
        match listener.accept() {
            Ok((s, _)) => {
                s.set_nonblocking(false)?;
                s.set_nodelay(true)?;
                return Ok(s);
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock && Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(5))
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                let waited = start.elapsed().as_secs_f64();
                return Err(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    format!("no peer connected in {waited:.1} s"),
                ));
            }
            Err(e) => return Err(e),
        }
    }
}

/// A TCP connection, read without blocking.
pub struct Tcp {
    stream: TcpStream,
    peeked: Option<u8>,
}

impl Tcp {
    /// Connects to `addr` (retrying for up to `wait` while the peer starts).
    pub fn connect(addr: &str, wait: Duration) -> std::io::Result<Self> {
        let start = Instant::now();
        loop {
            match TcpStream::connect(addr) {
                Ok(s) => return Self::wrap(s),
                Err(e) if start.elapsed() < wait => {
                    let _ = e;
                    std::thread::sleep(Duration::from_millis(100));
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// Accepts one connection on `listener`, waiting at most `wait`.
    pub fn accept(listener: &TcpListener, wait: Duration) -> std::io::Result<Self> {
        Self::wrap(accept_within(listener, Instant::now() + wait)?)
    }

    fn wrap(stream: TcpStream) -> std::io::Result<Self> {
        stream.set_nodelay(true)?;
        stream.set_nonblocking(true)?;
        Ok(Tcp { stream, peeked: None })
    }
}

impl embedded_io::ErrorType for Tcp {
    type Error = TransportError;
}

impl embedded_io::ReadReady for Tcp {
    fn read_ready(&mut self) -> Result<bool, TransportError> {
        if self.peeked.is_some() {
            return Ok(true);
        }
        let mut b = [0u8; 1];
        match self.stream.read(&mut b) {
            Ok(0) => Err(TransportError(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "peer closed"))),
            Ok(_) => {
                self.peeked = Some(b[0]);
                Ok(true)
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Ok(false),
            Err(e) => Err(TransportError(e)),
        }
    }
}

impl embedded_io::Read for Tcp {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, TransportError> {
        if buf.is_empty() {
            return Ok(0);
        }
        let mut n = 0;
        if let Some(b) = self.peeked.take() {
            buf[0] = b;
            n = 1;
        }
        match self.stream.read(&mut buf[n..]) {
            Ok(m) => Ok(n + m),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Ok(n),
            Err(e) if n > 0 => {
                let _ = e;
                Ok(n)
            }
            Err(e) => Err(TransportError(e)),
        }
    }
}

impl embedded_io::WriteReady for Tcp {
    /// The kernel takes what is written (pace with [`Paced`] to model a UART).
    fn write_ready(&mut self) -> Result<bool, TransportError> {
        Ok(true)
    }
}

impl embedded_io::Write for Tcp {
    fn write(&mut self, buf: &[u8]) -> Result<usize, TransportError> {
        loop {
            match self.stream.write(buf) {
                Ok(n) => return Ok(n),
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => std::thread::sleep(Duration::from_micros(200)),
                Err(e) => return Err(TransportError(e)),
            }
        }
    }
    fn flush(&mut self) -> Result<(), TransportError> {
        loop {
            match self.stream.flush() {
                Ok(()) => return Ok(()),
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => std::thread::sleep(Duration::from_micros(200)),
                Err(e) => return Err(TransportError(e)),
            }
        }
    }
}

/// A TCP connection written as it blocks (the far side of a relay or of
/// the line between two boards), as an `embedded-io` writer.
pub struct TcpWriter(pub TcpStream);

impl embedded_io::ErrorType for TcpWriter {
    type Error = TransportError;
}

impl embedded_io::Write for TcpWriter {
    fn write(&mut self, buf: &[u8]) -> Result<usize, TransportError> {
        self.0.write(buf).map_err(TransportError)
    }
    fn flush(&mut self) -> Result<(), TransportError> {
        self.0.flush().map_err(TransportError)
    }
}

#[cfg(feature = "serial")]
pub use serial::Serial;

#[cfg(feature = "serial")]
mod serial {
    use super::TransportError;
    use std::io::{Read as _, Write as _};
    use std::time::Duration;

    /// A serial port (8N1).
    pub struct Serial {
        port: Box<dyn serialport::SerialPort>,
    }

    impl Serial {
        /// Opens `device` at `baud`.
        pub fn open(device: &str, baud: u32) -> Result<Self, serialport::Error> {
            let port = serialport::new(device, baud).timeout(Duration::from_millis(10)).open()?;
            Ok(Serial { port })
        }
    }

    impl embedded_io::ErrorType for Serial {
        type Error = TransportError;
    }

    impl embedded_io::ReadReady for Serial {
        fn read_ready(&mut self) -> Result<bool, TransportError> {
            self.port.bytes_to_read().map(|n| n > 0).map_err(|e| TransportError(e.into()))
        }
    }

    impl embedded_io::Read for Serial {
        fn read(&mut self, buf: &mut [u8]) -> Result<usize, TransportError> {
            match self.port.read(buf) {
                Ok(n) => Ok(n),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Ok(0),
                Err(e) => Err(TransportError(e)),
            }
        }
    }

    impl embedded_io::WriteReady for Serial {
        /// Whether the driver's transmit queue is nearly empty, so that an
        /// acknowledgement written next leaves soon.
        fn write_ready(&mut self) -> Result<bool, TransportError> {
            self.port.bytes_to_write().map(|n| n < 16).map_err(|e| TransportError(e.into()))
        }
    }

    impl embedded_io::Write for Serial {
        fn write(&mut self, buf: &[u8]) -> Result<usize, TransportError> {
            self.port.write(buf).map_err(TransportError)
        }
        fn flush(&mut self) -> Result<(), TransportError> {
            self.port.flush().map_err(TransportError)
        }
    }
}

/// Wall-clock milliseconds since creation.
pub struct HostClock(Instant);

impl Default for HostClock {
    fn default() -> Self {
        HostClock(Instant::now())
    }
}

impl Clock for HostClock {
    fn now_ms(&self) -> u64 {
        self.0.elapsed().as_millis() as u64
    }
}

/// Times bytes as a UART sends them: byte k leaves `k * 10 / baud` seconds
/// after the start (8N1). An idle line banks no time: it restarts the count.
#[derive(Clone, Copy, Debug)]
pub struct Pacer {
    per_byte: f64,
    started: Instant,
    sent: u64,
}

impl Pacer {
    /// A pacer for `baud` (0: no pacing).
    pub fn new(baud: u32) -> Self {
        let per_byte = if baud == 0 { 0.0 } else { 10.0 / f64::from(baud) };
        Pacer { per_byte, started: Instant::now(), sent: 0 }
    }

    /// Waits until the next byte may leave.
    pub fn wait(&mut self) {
        if self.per_byte <= 0.0 {
            return;
        }
        let now = self.started.elapsed().as_secs_f64();
        let due = self.sent as f64 * self.per_byte;
        if due > now {
            std::thread::sleep(Duration::from_secs_f64(due - now));
        } else if now - due > 0.05 {
            self.sent = (now / self.per_byte) as u64;
        }
    }

    /// Whether a byte may leave now.
    pub fn ready(&self) -> bool {
        self.per_byte <= 0.0 || self.sent as f64 * self.per_byte <= self.started.elapsed().as_secs_f64()
    }

    /// Counts `n` bytes sent.
    pub fn sent(&mut self, n: usize) {
        self.sent += n as u64;
    }
}

/// A byte stream whose writes are paced to a baud rate ([`Pacer`]), as a
/// UART sends: over TCP the link's timeouts then mean what they mean on a
/// serial port.
pub struct Paced<T> {
    inner: T,
    pacer: Pacer,
}

impl<T> Paced<T> {
    /// `inner` paced to `baud` (0: unpaced).
    pub fn new(inner: T, baud: u32) -> Self {
        Paced { inner, pacer: Pacer::new(baud) }
    }
}

impl<T: embedded_io::ErrorType> embedded_io::ErrorType for Paced<T> {
    type Error = T::Error;
}

impl<T: embedded_io::Read> embedded_io::Read for Paced<T> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, T::Error> {
        self.inner.read(buf)
    }
}

impl<T: embedded_io::ReadReady> embedded_io::ReadReady for Paced<T> {
    fn read_ready(&mut self) -> Result<bool, T::Error> {
        self.inner.read_ready()
    }
}

impl<T: embedded_io::WriteReady> embedded_io::WriteReady for Paced<T> {
    fn write_ready(&mut self) -> Result<bool, T::Error> {
        Ok(self.pacer.ready() && self.inner.write_ready()?)
    }
}

impl<T: embedded_io::Write> embedded_io::Write for Paced<T> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, T::Error> {
        self.pacer.wait();
        let n = self.inner.write(buf)?;
        self.pacer.sent(n);
        Ok(n)
    }
    fn flush(&mut self) -> Result<(), T::Error> {
        self.inner.flush()
    }
}

/// 8N1 at `baud`: seconds a number of bytes takes on the line.
pub fn line_seconds(bytes: u64, baud: u32) -> f64 {
    bytes as f64 * 10.0 / f64::from(baud.max(1))
}
