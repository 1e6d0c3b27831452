//! Repairing a received codeword: substituted bytes corrected by the
//! code, a length off by one or two bytes explained by the edits (dropped
//! or duplicated bytes) tried at each position, judged on syndromes shifted
//! in place.

use super::super::rs::{alpha_pow, mul};
use super::*;

/// The received codeword bytes, with the replacement value read as zero.
#[derive(Clone, Copy)]
pub(super) struct Received<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) h: u8,
}

impl Received<'_> {
    fn len(&self) -> usize {
        self.bytes.len()
    }

    fn at(&self, i: usize) -> u8 {
        match self.bytes.get(i) {
            Some(&b) if b != self.h => b,
            _ => 0,
        }
    }
}

/// An explanation of a frame's length: where the line dropped bytes
/// (a zero is inserted before received byte `i`) or duplicated them
/// (received byte `i` removed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Edit {
    None,
    Drop(usize),
    Dup(usize),
    Drops(usize, usize),
    Dups(usize, usize),
    /// Insert before `.0`, remove `.1`.
    DropDup(usize, usize),
}

impl Edit {
    /// Writes the edited word into `out`; its length.
    fn apply(self, r: Received<'_>, out: &mut [u8]) -> usize {
        let mut at = 0;
        let mut put = |b: u8, at: &mut usize| {
            if let Some(o) = out.get_mut(*at) {
                *o = b;
            }
            *at += 1;
        };
        for i in 0..=r.len() {
            let inserts = match self {
                Edit::Drop(a) | Edit::DropDup(a, _) => usize::from(a == i),
                Edit::Drops(a, b) => usize::from(a == i) + usize::from(b == i),
                _ => 0,
            };
            for _ in 0..inserts {
                put(0, &mut at);
            }
            let removed = match self {
                Edit::Dup(a) | Edit::DropDup(_, a) => a == i,
                Edit::Dups(a, b) => a == i || b == i,
                _ => false,
            };
            if i < r.len() && !removed {
                put(r.at(i), &mut at);
            }
        }
        at
    }

    /// Indices of the inserted bytes in the edited word (as many as the
    /// edit inserts; the rest zero).
    fn erasures(self) -> [usize; 2] {
        match self {
            Edit::Drop(a) => [a, 0],
            Edit::Drops(a, b) => [a, b + 1],
            Edit::DropDup(a, b) if b >= a => [a, 0],
            Edit::DropDup(a, _) => [a.saturating_sub(1), 0],
            _ => [0, 0],
        }
    }

    /// Bytes the edit inserts (erasures).
    fn inserted(self) -> usize {
        match self {
            Edit::Drop(_) | Edit::DropDup(..) => 1,
            Edit::Drops(..) => 2,
            _ => 0,
        }
    }

    /// Where the edit begins in the received word.
    fn position(self) -> usize {
        match self {
            Edit::None => 0,
            Edit::Drop(a) | Edit::Dup(a) => a,
            Edit::Drops(a, b) | Edit::Dups(a, b) | Edit::DropDup(a, b) => a.min(b),
        }
    }

    fn damage(self, substituted: usize) -> Damage {
        let (dropped, duplicated) = match self {
            Edit::None => (0, 0),
            Edit::Drop(_) => (1, 0),
            Edit::Dup(_) => (0, 1),
            Edit::Drops(..) => (2, 0),
            Edit::Dups(..) => (0, 2),
            Edit::DropDup(..) => (1, 1),
        };
        Damage { substituted: substituted.min(255) as u8, dropped, duplicated }
    }
}

/// Right-aligned prefix sums of the received word `r` (`m` bytes), per
/// syndrome `j < p`: `A_j(k) = Σ_{i<k} r_i α^(j (m-1-i))`. An edit shifts
/// the bytes after it by whole positions, which multiplies their share of
/// a syndrome by a power of `α^j`: so the syndromes of any edited word
/// follow from `A` at the edit's positions in `O(p)`.
#[derive(Clone, Copy)]
struct Prefix {
    a: [u8; MAX_PARITY],
    /// `α^(j (m-1-k))`.
    pw: [u8; MAX_PARITY],
    k: usize,
}

impl Prefix {
    fn start(p: usize, m: usize) -> Self {
        let mut pw = [0u8; MAX_PARITY];
        for (j, w) in pw.iter_mut().enumerate().take(p) {
            *w = alpha_pow(j * ((m + 254) % 255));
        }
        Prefix { a: [0; MAX_PARITY], pw, k: 0 }
    }

    /// `r_k α^(j (m-1-k))`: byte `k`'s share of syndrome `j`.
    fn term(&self, j: usize, rk: u8) -> u8 {
        mul(rk, self.pw[j])
    }

    fn advance(&mut self, r: Received<'_>, p: usize) {
        let rk = r.at(self.k);
        for j in 0..p {
            self.a[j] ^= mul(rk, self.pw[j]);
            self.pw[j] = mul(self.pw[j], alpha_pow(255 - j % 255));
        }
        self.k += 1;
    }
}

/// Finds the codeword of `n` bytes, `p` of them parity, that the received
/// word explains with the fewest edits; writes the payload at the start of
/// `work`.
/// Without `checked` (a block's segment) the word carries no CRC: only the
/// code judges it (and the block's code and CRC after).
pub(super) fn decode(
    r: Received<'_>,
    p: usize,
    n: usize,
    work: &mut [u8],
    checked: bool,
) -> Result<(usize, Damage), DeframeError> {
    let m = r.len();
    if m < 5 {
        return Err(DeframeError::Short);
    }
    // The syndromes of the received word (Horner: one product a byte and
    // syndrome; every frame pays this, the edits' tries only a damaged one),
    // and the factors by which a drop or a duplicate at a position shifts
    // the bytes before it.
    let (mut t, mut drop_f, mut dup_f) = ([0u8; MAX_PARITY], [0u8; MAX_PARITY], [0u8; MAX_PARITY]);
    for j in 0..p {
        let a = alpha_pow(j);
        t[j] = (0..m).fold(0, |acc, i| mul(acc, a) ^ r.at(i));
        drop_f[j] = 1 ^ a;
        dup_f[j] = 1 ^ alpha_pow(255 - j % 255);
    }
    let mut s = [0u8; MAX_PARITY];
    let mut found = Found { r, work, p, n, checked, best: None };
    match m as isize - n as isize {
        0 => {
            found.consider(Edit::None, &t[..p]);
            if found.best.is_none() && p >= 4 && n <= PAIR_MAX {
                pairs(r, p, &t, &mut found, PairKind::DropDup);
            }
        }
        -1 => {
            let mut pa = Prefix::start(p, m);
            for a in 0..=m {
                for j in 0..p {
                    s[j] = t[j] ^ mul(drop_f[j], pa.a[j]);
                }
                found.consider(Edit::Drop(a), &s[..p]);
                if found.done(a) {
                    break;
                }
                pa.advance(r, p);
            }
        }
        1 => {
            let mut pa = Prefix::start(p, m);
            for a in 0..m {
                let ra = r.at(a);
                for j in 0..p {
                    s[j] = t[j] ^ pa.term(j, ra) ^ mul(dup_f[j], pa.a[j]);
                }
                found.consider(Edit::Dup(a), &s[..p]);
                if found.done(a) {
                    break;
                }
                pa.advance(r, p);
            }
        }
        -2 if p >= 3 && n <= PAIR_MAX => pairs(r, p, &t, &mut found, PairKind::Drops),
        2 if p >= 2 && n <= PAIR_MAX => pairs(r, p, &t, &mut found, PairKind::Dups),
        d if d > 2 => {
            // A lost delimiter: this frame, then (some of) the next.
            let first = Received { bytes: r.bytes.get(..n).unwrap_or(&[]), h: r.h };
            return decode(first, p, n, found.work, checked);
        }
        _ => {}
    }
    found.finish().ok_or(DeframeError::Checksum)
}

/// The best explanation of a damaged frame found so far: the one that
/// passes the code and the CRC with the fewest corrections (an edit
/// guessed a few bytes off the true position also passes, with the bytes
/// between counted as substituted).
struct Found<'r, 'w> {
    r: Received<'r>,
    work: &'w mut [u8],
    p: usize,
    n: usize,
    /// Whether the word ends in a CRC-32 of its data.
    checked: bool,
    best: Option<(usize, Edit, rs::Corrections)>,
}

impl Found<'_, '_> {
    /// Tries the word `edit` makes, its syndromes `s`: kept when the code
    /// explains it (a guess keeping one parity equation spare), the CRC
    /// holds, and it needs fewer corrections than the best so far.
    fn consider(&mut self, edit: Edit, s: &[u8]) {
        let (p, n) = (self.p, self.n);
        let e = edit.inserted();
        let guessed = edit != Edit::None;
        if guessed && p < e + 1 {
            return;
        }
        let max_errors = match edit {
            Edit::None => p / 2,
            Edit::Drop(_) | Edit::Dup(_) => (p - e - 1) / 2,
            // Pairs: at most one error more on longer codewords (`pairs`).
            _ if n <= PAIR_FULL => (p - e - 1) / 2,
            _ => ((p - e - 1) / 2).min(1),
        };
        let erasures = edit.erasures();
        let Some(fixes) = rs::solve(s, n, &erasures[..e], max_errors) else { return };
        let errors = fixes.errors(&erasures[..e]);
        if self.best.is_some_and(|b| b.0 <= errors) {
            return;
        }
        if self.rebuild(edit, &fixes).is_some() {
            self.best = Some((errors, edit, fixes));
        }
    }

    /// Writes the word `edit` makes into `work`, corrected; the payload's
    /// length if its CRC holds.
    fn rebuild(&mut self, edit: Edit, fixes: &rs::Corrections) -> Option<usize> {
        let (p, n) = (self.p, self.n);
        if edit.apply(self.r, self.work) != n || !fixes.apply(self.work.get_mut(..n)?) {
            return None;
        }
        if !self.checked {
            return Some(n - p);
        }
        let k = n - p - 4;
        let (payload, rest) = self.work.get(..n - p)?.split_at(k);
        (crc32(payload).to_le_bytes() == [rest[0], rest[1], rest[2], rest[3]]).then_some(k)
    }

    /// Whether a scan at `position` is past where a better explanation
    /// than the best could be.
    fn done(&self, position: usize) -> bool {
        self.best.is_some_and(|(errors, edit, _)| errors == 0 || position > edit.position() + self.p / 2 + 1)
    }

    /// The best explanation, rebuilt at the start of `work`: the payload's
    /// length and the damage.
    fn finish(mut self) -> Option<(usize, Damage)> {
        let (errors, edit, fixes) = self.best?;
        let k = self.rebuild(edit, &fixes)?;
        Some((k, edit.damage(errors)))
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum PairKind {
    Drops,
    Dups,
    DropDup,
}

/// Tries every pair of edits of `kind`, explanations with no other
/// error only (a pair leaves few equations to spare, and the tries are
/// many). Each try first computes the syndromes the first Forney syndrome
/// needs (one more than the edits insert) from prefix sums kept for those
/// alone; only the one try in 256 whose first Forney syndrome vanishes gets
/// the rest, from prefix sums made afresh. So the scan costs a few field
/// operations per pair of positions, what a small chip can afford.
fn pairs(r: Received<'_>, p: usize, t: &[u8; MAX_PARITY], found: &mut Found<'_, '_>, kind: PairKind) {
    let m = r.len();
    let n = found.n;
    let e = match kind {
        PairKind::Drops => 2,
        PairKind::DropDup => 1,
        PairKind::Dups => 0,
    };
    // Short codewords (a bad line's) get the full search, any error the
    // parity allows besides the edits; longer ones the quick check first:
    // syndromes for three Forney syndromes (one error besides the edits)
    // where the parity allows it with one equation spare, else for one.
    let full = n <= PAIR_FULL;
    let w = if full {
        p
    } else if p >= e + 4 {
        e + 3
    } else {
        e + 1
    };
    if p < e + 1 {
        return;
    }
    let mut s = [0u8; MAX_PARITY];
    let mut pa = Prefix::start(w, m);
    let last = if kind == PairKind::Dups { m } else { m + 1 };
    for a in 0..last {
        let mut pb = pa;
        for b in a..last {
            let edits: [Option<Edit>; 2] = match kind {
                PairKind::Drops => [Some(Edit::Drops(a, b)), None],
                PairKind::Dups => [(b > a).then_some(Edit::Dups(a, b)), None],
                // Insert before a and remove b (b >= a), or remove a and
                // insert before b (b > a + 1).
                PairKind::DropDup => {
                    [(b < m && b > a).then_some(Edit::DropDup(a, b)), (b > a + 1).then_some(Edit::DropDup(b, a))]
                }
            };
            for edit in edits.into_iter().flatten() {
                pair_syndromes(r, edit, (&pa, &pb), t, &mut s[..w]);
                if full {
                    found.consider(edit, &s[..p]);
                    continue;
                }
                if !few_errors(&s[..w], n, edit) {
                    continue;
                }
                let (fa, fb) = (prefix_at(r, p, a), prefix_at(r, p, b));
                pair_syndromes(r, edit, (&fa, &fb), t, &mut s[..p]);
                found.consider(edit, &s[..p]);
            }
            if b < m {
                pb.advance(r, w);
            }
        }
        if found.done(a) {
            return;
        }
        if a < m {
            pa.advance(r, w);
        }
    }
}

/// The prefix sums of the first `p` syndromes at byte `k`.
fn prefix_at(r: Received<'_>, p: usize, k: usize) -> Prefix {
    let mut x = Prefix::start(p, r.len());
    for _ in 0..k.min(r.len()) {
        x.advance(r, p);
    }
    x
}

/// Syndromes `s` (as many as `s` holds) of the word a pair of edits makes,
/// from the prefix sums at its two positions.
fn pair_syndromes(r: Received<'_>, edit: Edit, (pa, pb): (&Prefix, &Prefix), t: &[u8; MAX_PARITY], s: &mut [u8]) {
    let (a, b) = (pa.k, pb.k);
    let (ra, rb) = (r.at(a), r.at(b));
    for (j, sj) in s.iter_mut().enumerate() {
        let (up, down) = (alpha_pow(j), alpha_pow(255 - j % 255));
        *sj = match edit {
            Edit::Drops(..) => t[j] ^ mul(pa.a[j], mul(up, up) ^ up) ^ mul(pb.a[j], up ^ 1),
            Edit::Dups(..) => {
                let a1 = pa.a[j] ^ pa.term(j, ra);
                let b1 = pb.a[j] ^ pb.term(j, rb);
                mul(mul(down, down), pa.a[j]) ^ mul(down, pb.a[j] ^ a1) ^ t[j] ^ b1
            }
            Edit::DropDup(x, _) if x == a => {
                let b1 = pb.a[j] ^ pb.term(j, rb);
                pa.a[j] ^ mul(down, pb.a[j] ^ pa.a[j]) ^ t[j] ^ b1
            }
            _ => {
                // Remove a, insert before b.
                let a1 = pa.a[j] ^ pa.term(j, ra);
                pa.a[j] ^ mul(up, pb.a[j] ^ a1) ^ t[j] ^ pb.a[j]
            }
        };
    }
}

/// Whether syndromes `s` of a word of `n` bytes (the edit's erasures plus
/// one or three) may be explained by the erasures and at most one error
/// (three Forney syndromes `T` with `T1^2 = T0 T2`: one error's, or none's)
/// or, given one more only, by the erasures alone (`T0 = 0`). One wrong try
/// in about 256 passes, to be solved in full.
fn few_errors(s: &[u8], n: usize, edit: Edit) -> bool {
    let x = |i: usize| alpha_pow((n + 254 - i % 255) % 255);
    let er = edit.erasures();
    let e = edit.inserted();
    let gamma: [u8; 3] = match e {
        0 => [1, 0, 0],
        1 => [1, x(er[0]), 0],
        _ => {
            let (x1, x2) = (x(er[0]), x(er[1]));
            [1, x1 ^ x2, mul(x1, x2)]
        }
    };
    let forney = |i: usize| (0..=e).fold(0u8, |acc, k| acc ^ mul(gamma[k], s.get(i + e - k).copied().unwrap_or(0)));
    if s.len() >= e + 3 {
        let (t0, t1, t2) = (forney(0), forney(1), forney(2));
        mul(t1, t1) == mul(t0, t2) && (t0 != 0 || t1 == 0)
    } else {
        forney(0) == 0
    }
}
