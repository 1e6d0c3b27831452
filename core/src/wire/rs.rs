//! Reed-Solomon over GF(256): the forward error correction under the
//! framing. The code is the common one (field polynomial `0x11d`, generator
//! 2, first consecutive root `α^0`, systematic: message, then parity; the
//! first byte is the highest coefficient), the one of Python's `reedsolo`
//! with its defaults, which the golden vectors below and an end-to-end test
//! check against.
//!
//! A codeword of `n <= 255` bytes with `p` parity bytes corrects `e`
//! erasures (known positions) and `v` errors while `e + 2v <= p`. The
//! decoder is split so that a caller who tries many explanations of one
//! damaged frame (a byte dropped here or there) pays little per try:
//! [`syndromes`] once, then [`solve`] on syndromes it shifts itself.
//! Everything works in caller-owned fixed arrays; nothing allocates.

/// Most parity bytes a codeword carries.
pub const MAX_PARITY: usize = 32;
/// Longest codeword.
pub const MAX_CODEWORD: usize = 255;

const fn tables() -> ([u8; 512], [u8; 256]) {
    let (mut exp, mut log) = ([0u8; 512], [0u8; 256]);
    let mut x: u16 = 1;
    let mut i = 0;
    while i < 255 {
        exp[i] = x as u8;
        log[x as usize] = i as u8;
        x <<= 1;
        if x & 0x100 != 0 {
            x ^= 0x11d;
        }
        i += 1;
    }
    while i < 512 {
        exp[i] = exp[i - 255];
        i += 1;
    }
    (exp, log)
}

const TABLES: ([u8; 512], [u8; 256]) = tables();
static EXP: [u8; 512] = TABLES.0;
static LOG: [u8; 256] = TABLES.1;

/// `α^e`.
#[inline]
pub fn alpha_pow(e: usize) -> u8 {
    EXP[e % 255]
}

/// Product in GF(256).
#[inline]
pub fn mul(a: u8, b: u8) -> u8 {
    if a == 0 || b == 0 {
        0
    } else {
        EXP[(usize::from(LOG[usize::from(a)]) + usize::from(LOG[usize::from(b)])) & 511]
    }
}

/// Inverse of a non-zero element (0 for 0).
#[inline]
fn inv(a: u8) -> u8 {
    if a == 0 {
        0
    } else {
        EXP[(255 - usize::from(LOG[usize::from(a)])) & 511]
    }
}

/// Why a codeword could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RsError {
    /// More than [`MAX_PARITY`] parity bytes, an odd count, or a codeword
    /// longer than [`MAX_CODEWORD`].
    Shape,
}

/// The generator `∏ (x - α^i)`, `i < p`, highest coefficient first
/// (`g[0] = 1`), in `g[..=p]`.
fn generator(p: usize) -> [u8; MAX_PARITY + 1] {
    let mut g = [0u8; MAX_PARITY + 1];
    g[0] = 1;
    for i in 0..p.min(MAX_PARITY) {
        // g(x) * (x + α^i): each coefficient gains α^i times the one before.
        let root = alpha_pow(i);
        for k in (1..=i + 1).rev() {
            g[k] ^= mul(g[k - 1], root);
        }
    }
    g
}

/// Computes the `parity.len()` parity bytes of `message` (systematic: the
/// codeword is `message ++ parity`).
pub fn encode(message: &[u8], parity: &mut [u8]) -> Result<(), RsError> {
    let p = parity.len();
    if p > MAX_PARITY || message.len() + p > MAX_CODEWORD {
        return Err(RsError::Shape);
    }
    parity.fill(0);
    if p == 0 {
        return Ok(());
    }
    let g = generator(p);
    for &m in message {
        let feedback = m ^ parity[0];
        parity.copy_within(1.., 0);
        parity[p - 1] = 0;
        if feedback != 0 {
            for (r, &gk) in parity.iter_mut().zip(&g[1..=p]) {
                *r ^= mul(feedback, gk);
            }
        }
    }
    Ok(())
}

/// Syndromes `S_j = r(α^j)`, `j < s.len()`, of the received word `word`.
/// All zero: a codeword.
pub fn syndromes(word: &[u8], s: &mut [u8]) {
    for (j, sj) in s.iter_mut().enumerate() {
        let a = alpha_pow(j);
        *sj = word.iter().fold(0u8, |acc, &b| mul(acc, a) ^ b);
    }
}

/// Corrections [`solve`] found: `count` pairs of a byte index in the
/// codeword and the value to add (XOR) there.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Corrections {
    /// How many corrections.
    pub count: usize,
    /// Byte indices (from the start of the codeword).
    pub at: [u8; MAX_PARITY],
    /// Values to XOR in.
    pub value: [u8; MAX_PARITY],
}

impl Corrections {
    /// Applies them to `word`; false if an index lies outside it.
    pub fn apply(&self, word: &mut [u8]) -> bool {
        for k in 0..self.count.min(MAX_PARITY) {
            match word.get_mut(usize::from(self.at[k])) {
                Some(b) => *b ^= self.value[k],
                None => return false,
            }
        }
        true
    }

    /// Corrections at positions other than the given erasures: the errors.
    pub fn errors(&self, erasures: &[usize]) -> usize {
        (0..self.count.min(MAX_PARITY))
            .filter(|&k| !erasures.contains(&usize::from(self.at[k])) && self.value[k] != 0)
            .count()
    }
}

/// A polynomial of at most `MAX_PARITY` degree, lowest coefficient first.
type Poly = [u8; MAX_PARITY + 1];

/// The corrections that explain syndromes `s` (of a word of `n` bytes) with
/// erasures at the byte indices `erasures` and at most `max_errors` errors
/// elsewhere; `None` when no such explanation exists (too much damage: the
/// word is left alone). All syndromes zero and no erasure: no correction.
pub fn solve(s: &[u8], n: usize, erasures: &[usize], max_errors: usize) -> Option<Corrections> {
    let (p, e) = (s.len(), erasures.len());
    if p > MAX_PARITY || n > MAX_CODEWORD || n == 0 || e > p || erasures.iter().any(|&i| i >= n) {
        return None;
    }
    let mut none = Corrections { count: 0, at: [0; MAX_PARITY], value: [0; MAX_PARITY] };
    if e == 0 && s.iter().all(|&x| x == 0) {
        return Some(none);
    }
    // The locator of a byte index: X = α^(n-1-i).
    let locator = |i: usize| alpha_pow(n - 1 - i);
    // Erasure locator Γ(x) = ∏ (1 - X x).
    let mut gamma: Poly = [0; MAX_PARITY + 1];
    gamma[0] = 1;
    for (k, &i) in erasures.iter().enumerate() {
        let x = locator(i);
        for d in (1..=k + 1).rev() {
            gamma[d] ^= mul(gamma[d - 1], x);
        }
    }
    // Forney syndromes: the errors alone, with the erasures divided out.
    let mut t = [0u8; MAX_PARITY];
    for (i, ti) in t.iter_mut().enumerate().take(p - e) {
        *ti = (0..=e).fold(0, |acc, k| acc ^ mul(gamma[k], s[i + e - k]));
    }
    let (c, l) = berlekamp_massey(&t[..p - e], max_errors.min((p - e) / 2))?;
    // Errata locator Λ = C Γ.
    let mut lambda: Poly = [0; MAX_PARITY + 1];
    for (i, &ci) in c.iter().enumerate().take(l + 1) {
        for (k, &gk) in gamma.iter().enumerate().take(e + 1) {
            if let Some(d) = lambda.get_mut(i + k) {
                *d ^= mul(ci, gk);
            }
        }
    }
    let degree = l + e;
    // Chien search: the byte indices whose X^-1 is a root.
    let mut found = 0;
    for i in 0..n {
        let x_inv = inv(locator(i));
        if eval(&lambda[..=degree], x_inv) == 0 {
            if found == MAX_PARITY {
                return None;
            }
            none.at[found] = i as u8;
            found += 1;
        }
    }
    if found != degree {
        return None;
    }
    // Forney: Y = X Ω(X^-1) / Λ'(X^-1), Ω = S Λ mod x^p.
    let mut omega: Poly = [0; MAX_PARITY + 1];
    for (i, &si) in s.iter().enumerate() {
        for (k, &lk) in lambda.iter().enumerate().take(degree + 1) {
            if i + k < p {
                omega[i + k] ^= mul(si, lk);
            }
        }
    }
    for k in 0..found {
        let x = locator(usize::from(none.at[k]));
        let x_inv = inv(x);
        // Formal derivative: the odd terms, one degree down.
        let mut deriv = 0u8;
        let mut pow = 1u8;
        let x2 = mul(x_inv, x_inv);
        for d in (1..=degree).step_by(2) {
            deriv ^= mul(lambda[d], pow);
            pow = mul(pow, x2);
        }
        if deriv == 0 {
            return None;
        }
        none.value[k] = mul(mul(x, eval(&omega[..p], x_inv)), inv(deriv));
    }
    none.count = found;
    Some(none)
}

/// `poly(x)`, lowest coefficient first.
fn eval(poly: &[u8], x: u8) -> u8 {
    poly.iter().rev().fold(0, |acc, &c| mul(acc, x) ^ c)
}

/// The shortest LFSR (connection polynomial, lowest first, and its
/// length) generating `t`; `None` as soon as it is longer than `max_len`
/// (a candidate explanation rejected early: the length only grows).
fn berlekamp_massey(t: &[u8], max_len: usize) -> Option<(Poly, usize)> {
    let (mut c, mut b): (Poly, Poly) = ([0; MAX_PARITY + 1], [0; MAX_PARITY + 1]);
    c[0] = 1;
    b[0] = 1;
    let (mut l, mut m, mut last) = (0usize, 1usize, 1u8);
    for n in 0..t.len() {
        let mut d = t[n];
        for i in 1..=l.min(n) {
            d ^= mul(c[i], t[n - i]);
        }
        if d == 0 {
            m += 1;
            continue;
        }
        let coef = mul(d, inv(last));
        let before = c;
        for i in 0..=MAX_PARITY - m.min(MAX_PARITY) {
            if let (Some(&bi), true) = (b.get(i), i + m <= MAX_PARITY) {
                c[i + m] ^= mul(coef, bi);
            }
        }
        if 2 * l <= n {
            l = n + 1 - l;
            if l > max_len {
                return None;
            }
            b = before;
            last = d;
            m = 1;
        } else {
            m += 1;
        }
    }
    Some((c, l))
}

/// Decodes `word` in place (`p` parity bytes at its end) with erasures at
/// `erasures`; the number of bytes changed, or `None` when it is beyond
/// repair (then `word` is unchanged).
pub fn decode(word: &mut [u8], p: usize, erasures: &[usize]) -> Option<usize> {
    if p > MAX_PARITY {
        return None;
    }
    let mut s = [0u8; MAX_PARITY];
    syndromes(word, &mut s[..p]);
    let fixes = solve(&s[..p], word.len(), erasures, p / 2)?;
    let changed = (0..fixes.count).filter(|&k| fixes.value[k] != 0).count();
    fixes.apply(word).then_some(changed)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Golden codewords from Python's `reedsolo` 1.7.0 (`RSCodec(nsym)`
    /// with its defaults: `fcr=0, prim=0x11d, generator=2`):
    /// `RSCodec(4).encode(b"cosem")`, `RSCodec(8).encode(bytes(range(1, 21)))`
    /// and `RSCodec(2).encode(b"\x00\x00\x01")`.
    const GOLDEN: [(&[u8], usize, &[u8]); 3] = [
        (b"cosem", 4, &[0x63, 0x6f, 0x73, 0x65, 0x6d, 0xe4, 0xbf, 0x8b, 0xa7]),
        (
            &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20],
            8,
            &[
                1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 0x02, 0x95, 0x6e, 0x59, 0x6e,
                0xad, 0x46, 0x31,
            ],
        ),
        (&[0, 0, 1], 2, &[0, 0, 1, 0x03, 0x02]),
    ];

    #[test]
    fn field_tables_are_a_field() {
        for a in 1..=255u8 {
            assert_eq!(mul(a, inv(a)), 1);
        }
        assert_eq!(mul(0x80, 2), 0x1d);
    }

    #[test]
    fn golden_codewords_of_reedsolo() {
        for (msg, p, want) in GOLDEN {
            let mut parity = [0u8; MAX_PARITY];
            encode(msg, &mut parity[..p]).unwrap();
            assert_eq!(&parity[..p], &want[msg.len()..], "parity of {msg:?}");
            let mut s = [0u8; MAX_PARITY];
            syndromes(want, &mut s[..p]);
            assert!(s[..p].iter().all(|&x| x == 0));
        }
    }

    fn rng(state: &mut u64) -> u64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        *state
    }

    #[test]
    fn errors_and_erasures_within_the_bound_are_corrected() {
        let mut st = 0x0123_4567_89AB_CDEFu64;
        for trial in 0..3000 {
            let p = 2 * (1 + (rng(&mut st) % 16) as usize);
            let k = 1 + (rng(&mut st) % (255 - p) as u64) as usize;
            let n = k + p;
            let mut word = [0u8; 255];
            for b in word[..k].iter_mut() {
                *b = rng(&mut st) as u8;
            }
            let (msg, par) = word.split_at_mut(k);
            encode(msg, &mut par[..p]).unwrap();
            let clean = word;
            let e = (rng(&mut st) % (p as u64 + 1)) as usize;
            let v = (p - e) / 2;
            let mut pos = [0usize; 64];
            let mut count = 0;
            while count < (e + v).min(n) {
                let i = (rng(&mut st) % n as u64) as usize;
                if !pos[..count].contains(&i) {
                    pos[count] = i;
                    count += 1;
                }
            }
            for &i in &pos[..count] {
                word[i] ^= 1 + (rng(&mut st) % 255) as u8;
            }
            let erasures = &pos[..e.min(count)];
            let fixed = decode(&mut word[..n], p, erasures);
            assert!(fixed.is_some(), "trial {trial}: n {n} p {p} e {e} v {v}");
            assert_eq!(&word[..n], &clean[..n], "trial {trial}");
        }
    }

    #[test]
    fn too_many_errors_never_pass_as_a_different_codeword_silently() {
        // Beyond the bound the decoder either refuses or lands on another
        // codeword (which the frame's CRC then rejects); it never leaves a
        // non-codeword behind.
        let mut st = 42u64;
        for _ in 0..2000 {
            let (k, p) = (40, 8);
            let mut word = [0u8; 48];
            for b in word[..k].iter_mut() {
                *b = rng(&mut st) as u8;
            }
            let (msg, par) = word.split_at_mut(k);
            encode(msg, &mut par[..p]).unwrap();
            for _ in 0..6 {
                let i = (rng(&mut st) % 48) as usize;
                word[i] ^= 1 + (rng(&mut st) % 255) as u8;
            }
            let before = word;
            match decode(&mut word, p, &[]) {
                None => assert_eq!(word, before),
                Some(_) => {
                    let mut s = [0u8; 8];
                    syndromes(&word, &mut s);
                    assert!(s.iter().all(|&x| x == 0));
                }
            }
        }
    }

    #[test]
    fn shapes_out_of_range_are_refused() {
        let mut parity = [0u8; MAX_PARITY + 2];
        assert_eq!(encode(&[1; 10], &mut parity), Err(RsError::Shape));
        assert_eq!(encode(&[1; 250], &mut parity[..8]), Err(RsError::Shape));
        assert_eq!(solve(&[1, 2], 0, &[], 1), None);
        assert_eq!(solve(&[1, 2], 10, &[10], 1), None);
    }
}
