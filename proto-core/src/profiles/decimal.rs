//! Exact decimal arithmetic for tag values.
//!
//! Why: the config and the profiles write `scale` and `offset` as decimals (0.1, -273.15), and a
//! reader expects `raw x scale + offset` to be the decimal those numbers give (raw 2931 reads
//! 19.95). In binary floats 2931 x 0.1 - 273.15 is 19.950000000000045, and an `f32` 0.95 widened
//! to `f64` is 0.949999988079071. So a value is computed here on the decimals the numbers are
//! written with (the shortest decimal that reads back as the same float, the form Rust prints),
//! rounded to the places it is presented with, and only then turned into the nearest `f64`, whose
//! shortest form (what JSON writes) is that decimal again.
//!
//! Every operation is checked: a number too long for an `i128` of digits gives `None`, and the
//! callers fall back to float arithmetic (such a number is beyond what an `f64` holds exactly
//! anyway).

/// A decimal number: `digits / 10^places`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Decimal {
    digits: i128,
    places: u32,
}

/// 10^n, if it fits.
fn pow10(n: u32) -> Option<i128> {
    10i128.checked_pow(n)
}

// === impl Decimal ===

impl Decimal {
    /// A whole number.
    pub(crate) const fn int(n: i128) -> Self {
        Self {
            digits: n,
            places: 0,
        }
    }

    /// The shortest decimal that reads back as `x` (Rust's `Display` of the float); `None` for a
    /// number that is not finite or has too many digits.
    pub(crate) fn from_f64(x: f64) -> Option<Self> {
        if !x.is_finite() {
            return None;
        }
        Self::parse(&x.to_string())
    }

    /// The shortest decimal that reads back as the `f32` `x`: 0.95, not the
    /// 0.949999988079071 of the same number widened to `f64`.
    pub(crate) fn from_f32(x: f32) -> Option<Self> {
        if !x.is_finite() {
            return None;
        }
        Self::parse(&x.to_string())
    }

    /// A plain decimal text: an optional `-`, digits, optionally `.` and more digits.
    fn parse(text: &str) -> Option<Self> {
        let (negative, text) = match text.strip_prefix('-') {
            Some(rest) => (true, rest),
            None => (false, text),
        };
        let (whole, fraction) = text.split_once('.').unwrap_or((text, ""));
        let mut digits: i128 = 0;
        for c in whole.chars().chain(fraction.chars()) {
            let d = c.to_digit(10)?;
            digits = digits.checked_mul(10)?.checked_add(i128::from(d))?;
        }
        let places = u32::try_from(fraction.len()).ok()?;
        Some(
            Self {
                digits: if negative { -digits } else { digits },
                places,
            }
            .normalized(),
        )
    }

    /// Without trailing zeros after the point.
    fn normalized(mut self) -> Self {
        while self.places > 0 && self.digits % 10 == 0 {
            self.digits /= 10;
            self.places -= 1;
        }
        self
    }

    /// Places after the point, trailing zeros not counted.
    pub(crate) fn places(self) -> u32 {
        self.normalized().places
    }

    /// The same number with `places` places (at least its own).
    fn widened(self, places: u32) -> Option<Self> {
        let factor = pow10(places.checked_sub(self.places)?)?;
        Some(Self {
            digits: self.digits.checked_mul(factor)?,
            places,
        })
    }

    /// `self x other`, exactly.
    pub(crate) fn mul(self, other: Self) -> Option<Self> {
        Some(
            Self {
                digits: self.digits.checked_mul(other.digits)?,
                places: self.places.checked_add(other.places)?,
            }
            .normalized(),
        )
    }

    /// `self + other`, exactly.
    pub(crate) fn add(self, other: Self) -> Option<Self> {
        let places = self.places.max(other.places);
        let (a, b) = (self.widened(places)?, other.widened(places)?);
        Some(
            Self {
                digits: a.digits.checked_add(b.digits)?,
                places,
            }
            .normalized(),
        )
    }

    /// `self - other`, exactly.
    pub(crate) fn sub(self, other: Self) -> Option<Self> {
        self.add(Self {
            digits: other.digits.checked_neg()?,
            places: other.places,
        })
    }

    /// Rounded to `places` places, halves away from zero (19.945 -> 19.95, -0.25 -> -0.3).
    pub(crate) fn round(self, places: u32) -> Self {
        if self.places <= places {
            return self;
        }
        let Some(unit) = pow10(self.places - places) else {
            // More than 38 places to drop: every digit is below half a unit.
            return Self::int(0).normalized();
        };
        let (q, r) = (self.digits / unit, self.digits % unit);
        // |r| >= unit / 2, written so that it cannot overflow.
        let up = r.abs() >= unit - r.abs();
        Self {
            digits: if up { q + self.digits.signum() } else { q },
            places,
        }
        .normalized()
    }

    /// Rounded down (toward minus infinity) to `places` places.
    pub(crate) fn floor(self, places: u32) -> Self {
        self.step_to(places, false)
    }

    /// Rounded up (toward plus infinity) to `places` places.
    pub(crate) fn ceil(self, places: u32) -> Self {
        self.step_to(places, true)
    }

    fn step_to(self, places: u32, up: bool) -> Self {
        if self.places <= places {
            return self;
        }
        let Some(unit) = pow10(self.places - places) else {
            let toward = i128::from(up && self.digits > 0) - i128::from(!up && self.digits < 0);
            return Self {
                digits: toward,
                places,
            };
        };
        let (q, r) = (self.digits / unit, self.digits % unit);
        let q = match (up, r.signum()) {
            (true, 1) => q + 1,
            (false, -1) => q - 1,
            _ => q,
        };
        Self { digits: q, places }.normalized()
    }

    /// `self / other` as the nearest whole number, halves away from zero; `None` when `other` is
    /// zero or the digits do not fit.
    pub(crate) fn div_round(self, other: Self) -> Option<i128> {
        let (n, m) = self.ratio(other)?;
        let (q, r) = (n / m, n % m);
        let up = r.abs() >= m.abs() - r.abs();
        Some(if up { q + n.signum() * m.signum() } else { q })
    }

    /// `self / other` as the nearest `f64` the digits allow (one rounding while both fit 53
    /// bits); `None` when `other` is zero or the digits do not fit.
    pub(crate) fn div_f64(self, other: Self) -> Option<f64> {
        let (n, m) = self.ratio(other)?;
        if n % m == 0 {
            return Some((n / m) as f64);
        }
        Some(n as f64 / m as f64)
    }

    /// `self / other` as whole numerator and denominator, reduced.
    fn ratio(self, other: Self) -> Option<(i128, i128)> {
        if other.digits == 0 {
            return None;
        }
        // a / 10^p divided by b / 10^q = a x 10^q / (b x 10^p)
        let mut n = self.digits.checked_mul(pow10(other.places)?)?;
        let mut m = other.digits.checked_mul(pow10(self.places)?)?;
        let g = gcd(n, m);
        if g > 1 {
            n /= g;
            m /= g;
        }
        Some((n, m))
    }

    /// The nearest `f64` (correctly rounded, as Rust reads a decimal text).
    pub(crate) fn to_f64(self) -> f64 {
        let text = if self.places == 0 {
            self.digits.to_string()
        } else {
            format!("{}e-{}", self.digits, self.places)
        };
        text.parse().unwrap_or(f64::NAN)
    }
}

/// The greatest common divisor of `|a|` and `|b|` (0 when both are 0).
fn gcd(a: i128, b: i128) -> i128 {
    let (mut a, mut b) = (a.unsigned_abs(), b.unsigned_abs());
    while b != 0 {
        (a, b) = (b, a % b);
    }
    i128::try_from(a).unwrap_or(1)
}

/// Places after the point of the shortest decimal of `x` (0.1 -> 1, -273.15 -> 2, 20 -> 0);
/// `None` for a number that is not finite or too long to count.
pub(crate) fn places_of(x: f64) -> Option<u32> {
    Decimal::from_f64(x).map(Decimal::places)
}

/// The `f32` `x` as the `f64` of its shortest decimal (0.95f32 -> 0.95).
pub(crate) fn f32_shortest(x: f32) -> f64 {
    if x == 0.0 {
        // Keeps the sign of -0.0, which the digits do not carry.
        return f64::from(x);
    }
    // The f32's shortest text read as an f64: the f64 nearest that decimal.
    x.to_string().parse().unwrap_or(f64::from(x))
}

/// `x` rounded to `places` places by its float digits: the fallback where the exact digits do
/// not fit (the float then holds fewer places than asked anyway).
pub(crate) fn round_f64(x: f64, places: u32) -> f64 {
    if !x.is_finite() {
        return x;
    }
    let places = usize::try_from(places.min(350)).unwrap_or(350);
    format!("{x:.places$}").parse().unwrap_or(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d(text: &str) -> Decimal {
        Decimal::parse(text).expect("a decimal")
    }

    #[test]
    fn the_shortest_decimal_of_a_float_is_what_rust_prints() {
        assert_eq!(Decimal::from_f64(0.1), Some(d("0.1")));
        assert_eq!(Decimal::from_f64(-273.15), Some(d("-273.15")));
        assert_eq!(Decimal::from_f32(0.95), Some(d("0.95")));
        assert_eq!(
            Decimal::from_f64(f64::from(0.95f32)),
            Some(d("0.949999988079071"))
        );
        assert_eq!(Decimal::from_f64(f64::NAN), None);
        assert_eq!(Decimal::from_f64(1.5e300), None, "too many digits");
        assert_eq!(places_of(20.0), Some(0));
        assert_eq!(places_of(0.5), Some(1));
        assert_eq!(places_of(-273.15), Some(2));
    }

    #[test]
    fn arithmetic_is_exact_and_rounds_halves_away_from_zero() {
        let t = Decimal::int(2931)
            .mul(d("0.1"))
            .and_then(|v| v.add(d("-273.15")))
            .expect("fits");
        assert_eq!(t, d("19.95"));
        assert_eq!(t.to_f64(), 19.95);
        assert_eq!(d("19.945").round(2), d("19.95"));
        assert_eq!(d("-0.25").round(1), d("-0.3"));
        assert_eq!(d("4.549").round(1), d("4.5"));
        assert_eq!(d("4.57").floor(1), d("4.5"));
        assert_eq!(d("4.57").ceil(1), d("4.6"));
        assert_eq!(d("-4.57").floor(1), d("-4.6"));
        assert_eq!(d("-4.57").ceil(1), d("-4.5"));
        assert_eq!(d("19.95").sub(d("-273.15")), Some(d("293.1")));
        assert_eq!(d("293.1").div_round(d("0.1")), Some(2931));
        assert_eq!(d("4.6").div_f64(d("0.1")), Some(46.0));
        assert_eq!(d("30.25").div_round(d("0.5")), Some(61), "60.5 rounds away");
        assert_eq!(d("-30.25").div_round(d("0.5")), Some(-61));
        assert_eq!(d("1").div_round(Decimal::int(0)), None);
    }
}
