//! The receiving half of a courier: a peer's frame taken (its units put
//! in place, or its acknowledgement read), and this side's
//! acknowledgements, which carry the answer.

use super::{
    Courier, CourierConfig, CourierError, Flight, Reply, ACK_HEADER, ACK_RUNS, COMPLETE, COURIER_ACK, COURIER_DATA,
    DATA_HEADER, IN_FLIGHT, MAX_REPLY, REPLIED, RUNS_SHIFT, UNIT,
};
use embedded_io::Write;

impl Courier {
    /// One intact frame from the peer.
    pub(super) fn on_frame<L: Write>(
        &mut self,
        port: &mut L,
        p: &[u8],
        input: &mut [u8],
        now_ms: u64,
    ) -> Result<(), CourierError> {
        let u16_at = |i: usize| p.get(i..i + 2).and_then(|b| b.try_into().ok()).map(u16::from_le_bytes);
        let same = |r: Option<u16>| r.is_some_and(|r| Some(&(r as u8)) == p.get(1));
        match p.first().copied() {
            Some(COURIER_DATA) if p.len() >= DATA_HEADER => {
                let len = p.get(2..5).map_or(0, |b| b.iter().rev().fold(0u32, |a, &x| a << 8 | u32::from(x)));
                let first = u16_at(5).unwrap_or(0);
                let body = p.get(DATA_HEADER..).unwrap_or(&[]);
                // The round a message may come for: the one under way, or,
                // between rounds, the next (the last one's is answered).
                let next = self.last.map_or(0, |l| l.round.wrapping_add(1));
                let expected = self.round.unwrap_or(next);
                let last_round = self.last.map(|l| l.round).filter(|&r| r != expected);
                if same(Some(expected)) {
                    if self.in_round != Some(expected) {
                        self.receive(expected);
                    }
                    self.heard_ms = now_ms;
                    self.heard = true;
                    self.take_units(len, first, body, input)?;
                    let ack = self.ack_now();
                    self.send_answering(port, &ack)?;
                } else if let Some(last) = self.last.filter(|_| same(last_round)) {
                    // The peer missed the last round's answer.
                    let ack = AckView {
                        round: last.round,
                        count: last.units,
                        runs: [(0, 0); ACK_RUNS],
                        complete: true,
                        reply: Some(last.reply),
                    };
                    self.send_answering(port, &ack)?;
                }
            }
            Some(COURIER_ACK) if same(self.round) && p.len() >= ACK_HEADER => {
                let count = u16_at(2).unwrap_or(0);
                let flags = p.get(ACK_HEADER - 1).copied().unwrap_or(0);
                // The runs it holds (their count in the flags), then the answer.
                let held = usize::from(flags >> RUNS_SHIFT).min(ACK_RUNS);
                let body = ACK_HEADER + 4 * held;
                if p.len() < body {
                    return Ok(());
                }
                let mut runs = [(0u16, 0u16); ACK_RUNS];
                for (k, r) in runs.iter_mut().enumerate().take(held) {
                    *r = (u16_at(ACK_HEADER + 4 * k).unwrap_or(0), u16_at(ACK_HEADER + 2 + 4 * k).unwrap_or(0));
                }
                self.heard_ms = now_ms;
                self.heard = true;
                self.on_ack(usize::from(count), &runs, now_ms);
                if flags & REPLIED != 0 && flags & COMPLETE != 0 {
                    let reply = p.get(body..).unwrap_or(&[]);
                    let mut a = [0u8; MAX_REPLY];
                    let n = reply.len().min(MAX_REPLY);
                    a.get_mut(..n).unwrap_or(&mut []).copy_from_slice(reply.get(..n).unwrap_or(&[]));
                    self.answer = Some((a, n as u8));
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// What an acknowledgement says is held: the frames it covers leave
    /// the flight; those sent before the latest of them, not covered, were
    /// lost (the line keeps order) and go out again.
    fn on_ack(&mut self, count: usize, runs: &[(u16, u16); ACK_RUNS], now_ms: u64) {
        let units = Self::units(self.out_len);
        let before = self.acked.first_clear(0, units);
        for k in 0..count.min(units) {
            self.acked.set(k);
        }
        for &(start, len) in runs {
            let start = usize::from(start);
            for k in start..(start + usize::from(len)).min(units) {
                self.acked.set(k);
            }
        }
        let acked = &self.acked;
        let covered = |f: &Flight| acked.all(usize::from(f.first), usize::from(f.first) + usize::from(f.units));
        let Some(latest) = self.flights.iter().filter(|f| covered(f)).map(|f| f.seq).max() else { return };
        let mut kept: heapless::Deque<Flight, IN_FLIGHT> = heapless::Deque::new();
        while let Some(f) = self.flights.pop_front() {
            if covered(&f) {
                if !f.again {
                    let sample = 8 * now_ms.saturating_sub(f.sent_ms);
                    self.srtt8 = Some(self.srtt8.map_or(sample, |s| s - s / 8 + sample / 8));
                }
            } else if f.seq < latest {
                let _ = self.lost.push_back(f);
            } else {
                let _ = kept.push_back(f);
            }
        }
        self.flights = kept;
        if self.acked.first_clear(0, units) > before {
            self.backoff = 0;
            self.ceiling = self.ceiling.saturating_mul(2).min(self.config.max_units);
        }
    }

    /// Puts units of the peer's message in place.
    fn take_units(&mut self, len: u32, first: u16, body: &[u8], input: &mut [u8]) -> Result<(), CourierError> {
        if len as usize > input.len().min(CourierConfig::MAX_MESSAGE) {
            return Err(CourierError::TooLarge(len));
        }
        if *self.in_len.get_or_insert(len) != len {
            return Ok(());
        }
        let start = usize::from(first) * UNIT;
        let units = body.len().div_ceil(UNIT).max(1);
        let end = start + body.len();
        // Whole units, the last one short only at the message's end.
        let whole = body.len().is_multiple_of(UNIT) || end == len as usize;
        if !whole || end > len as usize || (body.is_empty() && len != 0) {
            return Ok(());
        }
        if let Some(dst) = input.get_mut(start..end) {
            dst.copy_from_slice(body);
            for k in 0..units {
                self.held.set(usize::from(first) + k);
            }
        }
        let n = Self::units(len);
        self.delivered |= self.held.first_clear(0, n) == n;
        Ok(())
    }

    /// The acknowledgement of what is held of this round's message now.
    fn ack_now(&self) -> AckView {
        let n = Self::units(self.in_len.unwrap_or(0));
        let count = self.held.first_clear(0, n);
        // The runs held beyond the gap: the first two and the last.
        let mut runs = [(0u16, 0u16); ACK_RUNS];
        let (mut k, mut found) = (count, 0usize);
        while k < n {
            let start = self.held.first_set(k, n);
            if start >= n {
                break;
            }
            let end = self.held.first_clear(start, n);
            let at = found.min(ACK_RUNS - 1);
            if let Some(r) = runs.get_mut(at) {
                *r = (start as u16, (end - start).min(usize::from(u16::MAX)) as u16);
            }
            found += 1;
            k = end;
        }
        AckView {
            round: self.in_round.unwrap_or(0),
            count: count as u16,
            runs,
            complete: self.delivered,
            reply: if self.delivered { self.replied } else { None },
        }
    }

    /// An acknowledgement; one of a whole message as many times as the
    /// line estimate says it takes for one to arrive but once in a hundred
    /// (a line that damages 10% of bytes loses about a third of them). Why:
    /// the peer's round ends only with it, and a lost one costs the peer a
    /// timeout (at least twice the round trip) and a resend before this
    /// side is asked again; a copy costs some 40 bytes.
    fn send_answering<L: Write>(&mut self, port: &mut L, ack: &AckView) -> Result<(), CourierError> {
        let copies = if ack.complete { self.answer_copies.max(1) } else { 1 };
        for _ in 0..copies {
            self.send_ack(port, ack)?;
        }
        Ok(())
    }

    pub(super) fn send_ack<L: Write>(&mut self, port: &mut L, ack: &AckView) -> Result<(), CourierError> {
        let mut p = [0u8; ACK_HEADER + 4 * ACK_RUNS + MAX_REPLY];
        let reply = ack.reply.as_ref().and_then(|(a, n)| a.get(..usize::from(*n))).unwrap_or(&[]);
        // Only the runs held: most acknowledgements have none, and a short
        // frame is what survives a line that damages many bytes.
        let held = ack.runs.iter().take_while(|r| r.1 > 0).count();
        let flags = (u8::from(ack.complete) * COMPLETE)
            | (u8::from(ack.reply.is_some()) * REPLIED)
            | ((held as u8) << RUNS_SHIFT);
        let runs = runs_bytes(&ack.runs);
        let mut at = 0;
        for part in [
            &[COURIER_ACK, ack.round as u8][..],
            &ack.count.to_le_bytes(),
            &[flags],
            runs.get(..4 * held).unwrap_or(&[]),
            reply,
        ] {
            p.get_mut(at..at + part.len()).ok_or(CourierError::Reply)?.copy_from_slice(part);
            at += part.len();
        }
        self.send(port, p.get(..at).unwrap_or(&[]))
    }

    /// After the caller answered: tells the peer at once (it may have
    /// nothing left to send that would ask).
    pub fn send_answer<L: Write>(&mut self, port: &mut L) -> Result<(), CourierError> {
        if self.round.is_none() || self.in_round != self.round || self.replied.is_none() {
            return Err(CourierError::Reply);
        }
        let ack = self.ack_now();
        self.send_answering(port, &ack)
    }
}

/// An acknowledgement's runs as its bytes (first unit, units: each
/// little-endian).
fn runs_bytes(runs: &[(u16, u16); ACK_RUNS]) -> [u8; 4 * ACK_RUNS] {
    let mut out = [0u8; 4 * ACK_RUNS];
    for (o, &(start, len)) in out.chunks_exact_mut(4).zip(runs) {
        let (s, l) = (start.to_le_bytes(), len.to_le_bytes());
        o.copy_from_slice(&[s[0], s[1], l[0], l[1]]);
    }
    out
}

/// An acknowledgement's fields.
pub(super) struct AckView {
    pub(super) round: u16,
    pub(super) count: u16,
    pub(super) runs: [(u16, u16); ACK_RUNS],
    pub(super) complete: bool,
    pub(super) reply: Option<Reply>,
}
