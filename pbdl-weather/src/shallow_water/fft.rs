//! A small complex FFT (iterative radix 2) with a direct DFT fallback for other lengths; the
//! longitude transforms of the model only ever need the lowest `M + 1` wavenumbers.

use super::Complex;

/// Plans for one transform length.
#[derive(Clone, Debug)]
pub(crate) struct Fft {
    n: usize,
    /// `exp(-2 pi i k / n)`, `k < n`.
    twiddle: Vec<Complex>,
    /// Bit-reversal permutation (radix-2 lengths only).
    rev: Vec<usize>,
    pow2: bool,
}

impl Fft {
    pub(crate) fn new(n: usize) -> Self {
        let twiddle = (0..n)
            .map(|k| {
                let a = -2.0 * std::f64::consts::PI * k as f64 / n as f64;
                Complex::new(a.cos(), a.sin())
            })
            .collect();
        let pow2 = n.is_power_of_two();
        let rev = if pow2 {
            let bits = n.trailing_zeros();
            (0..n).map(|i| if bits == 0 { 0 } else { i.reverse_bits() >> (usize::BITS - bits) }).collect()
        } else {
            Vec::new()
        };
        Self { n, twiddle, rev, pow2 }
    }

    /// In-place FFT with sign `-1` (forward) or `+1` (inverse, unscaled) in the exponent.
    fn fft_in_place(&self, buf: &mut [Complex], inverse: bool) {
        let n = self.n;
        for i in 0..n {
            let j = self.rev[i];
            if j > i {
                buf.swap(i, j);
            }
        }
        let mut len = 2;
        while len <= n {
            let half = len / 2;
            let stride = n / len;
            for start in (0..n).step_by(len) {
                for k in 0..half {
                    let mut w = self.twiddle[k * stride];
                    if inverse {
                        w = w.conj();
                    }
                    let a = buf[start + k];
                    let b = buf[start + k + half] * w;
                    buf[start + k] = a + b;
                    buf[start + k + half] = a - b;
                }
            }
            len *= 2;
        }
    }

    /// `out[m] = (1/n) sum_k row[k] exp(-2 pi i m k / n)` for `m < out.len()`; `buf` has length `n`.
    pub(crate) fn analyse_row(&self, row: &[f64], out: &mut [Complex], buf: &mut [Complex]) {
        let n = self.n;
        let scale = 1.0 / n as f64;
        if self.pow2 {
            for (b, r) in buf.iter_mut().zip(row) {
                *b = Complex::new(*r, 0.0);
            }
            self.fft_in_place(buf, false);
            for (o, b) in out.iter_mut().zip(buf.iter()) {
                *o = *b * scale;
            }
        } else {
            for (m, o) in out.iter_mut().enumerate() {
                let mut s = Complex::ZERO;
                for (k, r) in row.iter().enumerate() {
                    s += self.twiddle[(m * k) % n] * *r;
                }
                *o = s * scale;
            }
        }
    }

    /// `row[k] = F_0 + 2 Re sum_{m >= 1} F_m exp(2 pi i m k / n)` from `coef = F_0..F_M` (M < n/2).
    pub(crate) fn synthesise_row(&self, coef: &[Complex], row: &mut [f64], buf: &mut [Complex]) {
        let n = self.n;
        if self.pow2 {
            buf.fill(Complex::ZERO);
            for (m, c) in coef.iter().enumerate() {
                buf[m] = if m == 0 { Complex::new(c.re, 0.0) } else { *c * 2.0 };
            }
            self.fft_in_place(buf, true);
            for (r, b) in row.iter_mut().zip(buf.iter()) {
                *r = b.re;
            }
        } else {
            for (k, r) in row.iter_mut().enumerate() {
                let mut s = coef[0].re;
                for (m, c) in coef.iter().enumerate().skip(1) {
                    let w = self.twiddle[(m * k) % n].conj();
                    s += 2.0 * (c.re * w.re - c.im * w.im);
                }
                *r = s;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fft_matches_direct_dft_and_round_trips() {
        for n in [64usize, 128, 48] {
            let fft = Fft::new(n);
            let direct = Fft { pow2: false, ..fft.clone() };
            let row: Vec<f64> = (0..n).map(|k| ((k * 7 + 3) % 11) as f64 - 5.0 + (k as f64 * 0.3).sin()).collect();
            let mut buf = vec![Complex::ZERO; n];
            let mut a = vec![Complex::ZERO; n / 2];
            let mut b = vec![Complex::ZERO; n / 2];
            fft.analyse_row(&row, &mut a, &mut buf);
            direct.analyse_row(&row, &mut b, &mut buf);
            for (x, y) in a.iter().zip(&b) {
                assert!((*x - *y).abs() < 1e-12);
            }
            // A band-limited row (no Nyquist term) comes back exactly.
            let coef: Vec<Complex> =
                (0..n / 2 - 1).map(|m| Complex::new(1.0 / (m as f64 + 1.0), m as f64 * 0.1)).collect();
            let coef: Vec<Complex> =
                coef.iter().enumerate().map(|(m, c)| if m == 0 { Complex::new(c.re, 0.0) } else { *c }).collect();
            let mut r = vec![0.0; n];
            let mut r2 = vec![0.0; n];
            fft.synthesise_row(&coef, &mut r, &mut buf);
            direct.synthesise_row(&coef, &mut r2, &mut buf);
            let mut back = vec![Complex::ZERO; coef.len()];
            fft.analyse_row(&r, &mut back, &mut buf);
            for k in 0..n {
                assert!((r[k] - r2[k]).abs() < 1e-12);
            }
            for (x, y) in back.iter().zip(&coef) {
                assert!((*x - *y).abs() < 1e-13);
            }
        }
    }
}
