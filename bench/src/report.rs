//! The table of results: one row per measurement, its reference, the ratio (or value) compared
//! with the target, and PASS or FAIL.

use std::fmt::Write as _;

/// How a row's score is compared with its limit.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Op {
    /// The score must be at least the limit.
    AtLeast,
    /// The score must be at most the limit.
    AtMost,
}

/// A row's target.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Target {
    pub(crate) op: Op,
    pub(crate) limit: f64,
    /// The unit of score and limit ("" for a ratio).
    pub(crate) unit: &'static str,
}

// === impl Target ===

impl Target {
    pub(crate) const fn at_least(limit: f64) -> Self {
        Self {
            op: Op::AtLeast,
            limit,
            unit: "",
        }
    }

    pub(crate) const fn at_most(limit: f64) -> Self {
        Self {
            op: Op::AtMost,
            limit,
            unit: "",
        }
    }

    pub(crate) const fn with_unit(self, unit: &'static str) -> Self {
        Self { unit, ..self }
    }

    fn met_by(self, score: f64) -> bool {
        match self.op {
            Op::AtLeast => score >= self.limit,
            Op::AtMost => score <= self.limit,
        }
    }

    fn text(self) -> String {
        let op = match self.op {
            Op::AtLeast => ">=",
            Op::AtMost => "<=",
        };
        format!("{op} {}{}", trim(self.limit), self.unit)
    }
}

fn trim(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_owned()
}

/// One measurement.
#[derive(Clone, Debug)]
pub(crate) struct Row {
    /// What was measured.
    pub(crate) name: String,
    /// The gateway's figure.
    pub(crate) measured: String,
    /// What it is compared with (the best case, the bare server, the run without a fault).
    pub(crate) reference: String,
    /// The ratio (or the value, in the target's unit) held against the target.
    pub(crate) score: f64,
    pub(crate) target: Target,
    /// How the figure decomposes, conditions of the run.
    pub(crate) note: String,
}

// === impl Row ===

impl Row {
    pub(crate) fn passed(&self) -> bool {
        self.score.is_finite() && self.target.met_by(self.score)
    }
}

/// Renders the table (plain text, fixed columns, notes last).
pub(crate) fn render(rows: &[Row]) -> String {
    let headers = [
        "measurement",
        "gateway",
        "reference",
        "ratio/value",
        "target",
        "result",
    ];
    let cells: Vec<[String; 6]> = rows
        .iter()
        .map(|r| {
            [
                r.name.clone(),
                r.measured.clone(),
                r.reference.clone(),
                format!("{:.3}{}", r.score, r.target.unit),
                r.target.text(),
                if r.passed() { "PASS" } else { "FAIL" }.to_owned(),
            ]
        })
        .collect();
    let mut widths = headers.map(str::len);
    for row in &cells {
        for (w, c) in widths.iter_mut().zip(row) {
            *w = (*w).max(c.chars().count());
        }
    }
    let mut out = String::new();
    let line = |out: &mut String, cols: &[String]| {
        let mut s = String::new();
        for (i, (c, w)) in cols.iter().zip(widths).enumerate() {
            if i > 0 {
                s.push_str(" | ");
            }
            let pad = w.saturating_sub(c.chars().count());
            s.push_str(c);
            s.push_str(&" ".repeat(pad));
        }
        let _ = writeln!(out, "{}", s.trim_end());
    };
    line(&mut out, &headers.map(str::to_owned));
    line(&mut out, &widths.map(|w| "-".repeat(w)));
    for row in &cells {
        line(&mut out, row);
    }
    let passed = rows.iter().filter(|r| r.passed()).count();
    let _ = writeln!(out, "\n{passed} of {} rows meet their target.", rows.len());
    let notes: Vec<&Row> = rows.iter().filter(|r| !r.note.is_empty()).collect();
    if !notes.is_empty() {
        let _ = writeln!(out, "\nNotes:");
        for r in notes {
            let _ = writeln!(out, "- {}: {}", r.name, r.note);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_pass_by_their_target() {
        let row = |score, target| Row {
            name: "x".into(),
            measured: String::new(),
            reference: String::new(),
            score,
            target,
            note: String::new(),
        };
        assert!(row(0.95, Target::at_least(0.95)).passed());
        assert!(!row(0.949, Target::at_least(0.95)).passed());
        assert!(row(2.0, Target::at_most(2.0)).passed());
        assert!(!row(f64::NAN, Target::at_most(2.0)).passed());
        let table = render(&[row(1.0, Target::at_most(1.0).with_unit(" ms"))]);
        assert!(table.contains("<= 1 ms"), "{table}");
        assert!(table.contains("PASS"), "{table}");
    }
}
