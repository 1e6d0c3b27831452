//! The one fault model of a byte stream: each byte, with probability
//! `rate`, damaged as a [`Mix`] says (one bit flipped, replaced by another
//! value, dropped, or sent twice), from a seeded generator. The simulated
//! line ([`super::SimLine`]) draws its damage here, and [`Lossy`] puts the
//! same damage on what is written to any `embedded-io` port (the host's
//! relay between two `cosem link`s, the line between two boards' UARTs).

/// How a damaged byte is damaged, in shares (weights of any scale): one
/// bit flipped, the byte replaced by another value (XOR with a random
/// non-zero byte), dropped, duplicated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mix {
    /// One bit flipped.
    pub bit: f64,
    /// Replaced by another value.
    pub byte: f64,
    /// Dropped.
    pub drop: f64,
    /// Sent twice.
    pub dup: f64,
}

/// Why a mix could not be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MixError {
    /// A part is not `KIND=SHARE`.
    Syntax,
    /// A kind other than `bit`, `byte`, `drop`, `dup`.
    Kind,
    /// A share that is not a finite number of at least 0.
    Share,
    /// The shares add up to nothing.
    Empty,
    /// The shares add up to more than a finite number.
    Overflow,
    /// A kind given twice.
    Duplicate,
}

impl core::fmt::Display for MixError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            MixError::Syntax => "a mix is KIND=SHARE,... (kinds bit, byte, drop, dup)",
            MixError::Kind => "a kind of damage is bit, byte, drop or dup",
            MixError::Share => "a share is a finite number, 0 or more",
            MixError::Empty => "the shares add up to nothing",
            MixError::Overflow => "the shares add up to more than a finite number",
            MixError::Duplicate => "a kind of damage is given twice",
        })
    }
}

impl Mix {
    /// Replaced, dropped or duplicated, a third each: the simulator's
    /// damage before mixes existed, and an independent relay's.
    pub const THIRDS: Mix = Mix { bit: 0.0, byte: 1.0, drop: 1.0, dup: 1.0 };

    /// Reads `bit=S,byte=S,drop=S,dup=S` (a kind left out has no share,
    /// none given twice); the shares are finite, at least 0, and add up
    /// to a positive finite number.
    pub fn parse(text: &str) -> Result<Mix, MixError> {
        let mut mix = Mix { bit: 0.0, byte: 0.0, drop: 0.0, dup: 0.0 };
        let mut given = [false; 4];
        for part in text.split(',') {
            let (key, value) = part.split_once('=').ok_or(MixError::Syntax)?;
            let share: f64 = value.trim().parse().map_err(|_| MixError::Share)?;
            if !(share.is_finite() && share >= 0.0) {
                return Err(MixError::Share);
            }
            let (k, slot) = match key.trim() {
                "bit" => (0, &mut mix.bit),
                "byte" => (1, &mut mix.byte),
                "drop" => (2, &mut mix.drop),
                "dup" => (3, &mut mix.dup),
                _ => return Err(MixError::Kind),
            };
            if core::mem::replace(&mut given[k], true) {
                return Err(MixError::Duplicate);
            }
            *slot = share;
        }
        let total = mix.total();
        if !total.is_finite() {
            Err(MixError::Overflow)
        } else if total > 0.0 {
            Ok(mix)
        } else {
            Err(MixError::Empty)
        }
    }

    fn total(&self) -> f64 {
        self.bit + self.byte + self.drop + self.dup
    }

    /// The kind of damage of the draw `x` in `[0, 1)`: 0 bit, 1 byte, 2
    /// drop, 3 dup.
    pub fn kind(&self, x: f64) -> u8 {
        let x = x * self.total();
        if x < self.bit {
            0
        } else if x < self.bit + self.byte {
            1
        } else if x < self.bit + self.byte + self.drop {
            2
        } else {
            3
        }
    }
}

/// The simulation's generator (xorshift64): seeded, the same draws on any
/// machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SimRng(u64);

impl SimRng {
    /// A generator seeded with `seed` (any value; 0 too).
    pub fn new(seed: u64) -> Self {
        SimRng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// A number in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Why a fault could not be made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultError {
    /// The rate is not a probability (a finite number in `[0, 1]`).
    Rate,
    /// The mix's shares are not finite, non-negative with a positive sum.
    Mix,
}

impl core::fmt::Display for FaultError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FaultError::Rate => "an error rate is a probability, from 0 to 1",
            FaultError::Mix => "a mix's shares are finite, 0 or more, and add up to a positive number",
        })
    }
}

/// What a line does to bytes: each byte damaged with probability `rate`,
/// as `mix` says.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fault {
    /// Probability that a byte is damaged.
    pub rate: f64,
    /// How a damaged byte is damaged.
    pub mix: Mix,
}

/// What one byte became.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Damaged {
    /// Passed as it was.
    Kept(u8),
    /// Passed with another value (a bit flipped, or replaced).
    Changed(u8),
    /// Lost.
    Dropped,
    /// Sent twice.
    Doubled(u8),
}

impl Fault {
    /// A line that passes every byte.
    pub const NONE: Fault = Fault { rate: 0.0, mix: Mix::THIRDS };

    /// A fault of `rate` damaging as `mix` says, both checked.
    pub fn new(rate: f64, mix: Mix) -> Result<Fault, FaultError> {
        if !(rate.is_finite() && (0.0..=1.0).contains(&rate)) {
            return Err(FaultError::Rate);
        }
        let shares = [mix.bit, mix.byte, mix.drop, mix.dup];
        let total: f64 = shares.iter().sum();
        if !(shares.iter().all(|s| s.is_finite() && *s >= 0.0) && total.is_finite() && total > 0.0) {
            return Err(FaultError::Mix);
        }
        Ok(Fault { rate, mix })
    }

    /// Byte `b` through the fault, drawing from `rng`. With
    /// [`Mix::THIRDS`] the kind is drawn as the simulator drew it before
    /// mixes existed (so seeded runs are what they were).
    pub fn damage(&self, rng: &mut SimRng, b: u8) -> Damaged {
        // unit() is never NaN: a NaN rate damages nothing.
        if rng.unit() >= self.rate || self.rate.is_nan() {
            return Damaged::Kept(b);
        }
        let mix = self.mix;
        let kind = if mix == Mix::THIRDS { 1 + (rng.next_u64() % 3) as u8 } else { mix.kind(rng.unit()) };
        match kind {
            0 => Damaged::Changed(b ^ (1u8 << (rng.next_u64() % 8))),
            1 => Damaged::Changed(b ^ ((rng.next_u64() as u8) | 1)),
            2 => Damaged::Dropped,
            _ => Damaged::Doubled(b),
        }
    }
}

/// Any `embedded-io` port with a [`Fault`] on what is written through it
/// (reads pass as they are): the one fault injection over a real port.
pub struct Lossy<P> {
    port: P,
    fault: Fault,
    rng: SimRng,
    damaged: u64,
}

impl<P> Lossy<P> {
    /// `port` behind `fault`, its draws seeded with `seed`.
    pub fn new(port: P, fault: Fault, seed: u64) -> Self {
        Lossy { port, fault, rng: SimRng::new(seed), damaged: 0 }
    }

    /// Bytes damaged so far (changed, dropped or doubled).
    pub fn damaged(&self) -> u64 {
        self.damaged
    }

    /// The port.
    pub fn into_inner(self) -> P {
        self.port
    }
}

impl<P: embedded_io::ErrorType> embedded_io::ErrorType for Lossy<P> {
    type Error = P::Error;
}

impl<P: embedded_io::Read> embedded_io::Read for Lossy<P> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, P::Error> {
        self.port.read(buf)
    }
}

impl<P: embedded_io::ReadReady> embedded_io::ReadReady for Lossy<P> {
    fn read_ready(&mut self) -> Result<bool, P::Error> {
        self.port.read_ready()
    }
}

impl<P: embedded_io::WriteReady> embedded_io::WriteReady for Lossy<P> {
    fn write_ready(&mut self) -> Result<bool, P::Error> {
        self.port.write_ready()
    }
}

impl<P: embedded_io::Write> embedded_io::Write for Lossy<P> {
    /// Takes up to 64 bytes, damages them and writes what they became
    /// whole (at most twice as many).
    fn write(&mut self, buf: &[u8]) -> Result<usize, P::Error> {
        let take = buf.len().min(64);
        let mut out = [0u8; 128];
        let mut n = 0;
        for &b in buf.iter().take(take) {
            let d = self.fault.damage(&mut self.rng, b);
            let bytes: (Option<u8>, Option<u8>) = match d {
                Damaged::Kept(v) => (Some(v), None),
                Damaged::Changed(v) => (Some(v), None),
                Damaged::Dropped => (None, None),
                Damaged::Doubled(v) => (Some(v), Some(v)),
            };
            self.damaged += u64::from(!matches!(d, Damaged::Kept(_)));
            for v in [bytes.0, bytes.1].into_iter().flatten() {
                if let Some(slot) = out.get_mut(n) {
                    *slot = v;
                    n += 1;
                }
            }
        }
        self.port.write_all(out.get(..n).unwrap_or(&[]))?;
        Ok(take)
    }

    fn flush(&mut self) -> Result<(), P::Error> {
        self.port.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::vec::Vec;

    /// A port that keeps what it is given.
    struct Keep(Vec<u8>);

    impl embedded_io::ErrorType for Keep {
        type Error = core::convert::Infallible;
    }

    impl embedded_io::Write for Keep {
        fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
            self.0.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
    }

    fn through(fault: Fault, seed: u64, bytes: &[u8]) -> (Vec<u8>, u64) {
        use embedded_io::Write;
        let mut lossy = Lossy::new(Keep(Vec::new()), fault, seed);
        lossy.write_all(bytes).unwrap();
        let damaged = lossy.damaged();
        (lossy.into_inner().0, damaged)
    }

    #[test]
    fn a_clean_fault_passes_every_byte_and_a_silent_one_none() {
        let bytes: Vec<u8> = (0..=255).cycle().take(5000).collect();
        assert_eq!(through(Fault::NONE, 3, &bytes), (bytes.clone(), 0));
        let silent = Fault::new(1.0, Mix { bit: 0.0, byte: 0.0, drop: 1.0, dup: 0.0 }).unwrap();
        assert_eq!(through(silent, 3, &bytes), (Vec::new(), 5000));
    }

    /// Damage at the rate and in the shares asked, the same for the same
    /// seed.
    #[test]
    fn damage_follows_the_rate_and_the_shares() {
        let bytes = [0x55u8; 40_000];
        let mix = Mix { bit: 1.0, byte: 0.0, drop: 1.0, dup: 2.0 };
        let (out, damaged) = through(Fault::new(0.1, mix).unwrap(), 9, &bytes);
        assert!((3_600..4_400).contains(&damaged), "{damaged}");
        // A quarter of the damage drops a byte, half of it adds one.
        let grown = out.len() as i64 - bytes.len() as i64;
        assert!((700..1_300).contains(&grown), "{grown}");
        let flipped = out.iter().filter(|&&b| b != 0x55).count();
        assert!(out.iter().all(|b| b == &0x55 || (b ^ 0x55).count_ones() == 1), "bit flips only");
        assert!((800..1_200).contains(&flipped), "{flipped}");
        assert_eq!(through(Fault::new(0.1, mix).unwrap(), 9, &bytes), (out, damaged));
    }

    #[test]
    fn rates_and_mixes_are_checked() {
        for rate in [-0.1, 1.5, f64::NAN, f64::INFINITY] {
            assert_eq!(Fault::new(rate, Mix::THIRDS), Err(FaultError::Rate));
        }
        let zero = Mix { bit: 0.0, byte: 0.0, drop: 0.0, dup: 0.0 };
        let huge = Mix { bit: f64::MAX, byte: f64::MAX, drop: 0.0, dup: 0.0 };
        assert_eq!(Fault::new(0.1, zero), Err(FaultError::Mix));
        assert_eq!(Fault::new(0.1, huge), Err(FaultError::Mix));
    }
}
