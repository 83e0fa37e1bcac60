//! Reads typed values out of spanned TOML tables, collecting every problem with its line.

use super::error::{Problem, ProblemKind};
use crate::time::duration::{no_unit_advice, parse_duration, DurationError, ACCEPTED_FORMS};
use std::ops::Range;
use std::time::Duration;
use toml::de::{DeTable, DeValue};
use toml::Spanned;

/// Collects problems while a document is read, and turns byte offsets into line numbers.
pub(super) struct Reader<'t> {
    file: String,
    text: &'t str,
    problems: Vec<(usize, Problem)>,
}

impl<'t> Reader<'t> {
    pub(super) fn new(file: &str, text: &'t str) -> Self {
        Self {
            file: file.to_string(),
            text,
            problems: Vec::new(),
        }
    }

    /// The 1-based line holding byte `offset`.
    pub(super) fn line_of(&self, offset: usize) -> usize {
        line_and_column(self.text, offset).0
    }

    /// Records a problem with `key` found at `at`.
    pub(super) fn report(&mut self, at: &Range<usize>, key: String, kind: ProblemKind) {
        let problem = Problem {
            file: self.file.clone(),
            line: self.line_of(at.start),
            key,
            kind,
        };
        self.problems.push((at.start, problem));
    }

    /// Reads `key` of `table` with `convert`: `None` when absent, or when the value is wrong
    /// (then the problem is recorded at the value).
    pub(super) fn read<T>(
        &mut self,
        table: &TableRef<'_, '_>,
        key: &str,
        convert: impl FnOnce(&DeValue<'_>) -> Result<T, ProblemKind>,
    ) -> Option<T> {
        let value = table.get(key)?;
        match convert(value.get_ref()) {
            Ok(v) => Some(v),
            Err(kind) => {
                self.report(&value.span(), table.key_path(key), kind);
                None
            }
        }
    }

    /// Records an unknown-key problem for each key of `table` not in `known`.
    pub(super) fn check_keys(&mut self, table: &TableRef<'_, '_>, known: &'static [&'static str]) {
        for (key, _) in table.table.iter() {
            let name: &str = key.get_ref();
            if !known.contains(&name) {
                self.report(
                    &key.span(),
                    table.key_path(name),
                    ProblemKind::UnknownKey {
                        known,
                        near: crate::suggest::closest(name, known.iter().copied()),
                    },
                );
            }
        }
    }

    /// Records that `key` is required in `table`, at the table's header.
    pub(super) fn missing(&mut self, table: &TableRef<'_, '_>, key: &str, hint: &'static str) {
        self.report(
            &table.span,
            table.key_path(key),
            ProblemKind::Missing { hint },
        );
    }

    /// Every problem recorded, in the order of the file.
    pub(super) fn finish(mut self) -> Vec<Problem> {
        self.problems.sort_by_key(|(offset, _)| *offset);
        self.problems.into_iter().map(|(_, p)| p).collect()
    }
}

/// The 1-based line and column (in characters) of byte `offset` of `text`.
pub(super) fn line_and_column(text: &str, offset: usize) -> (usize, usize) {
    let mut end = offset.min(text.len());
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    let before = text.get(..end).unwrap_or("");
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = before.get(line_start..).map_or(0, |s| s.chars().count()) + 1;
    (line, column)
}

/// A table being read: where it is and its dotted path.
pub(super) struct TableRef<'a, 'i> {
    /// Dotted path, empty for the document itself.
    pub(super) path: String,
    /// Where the table starts (its header, for `[a.b]` tables).
    pub(super) span: Range<usize>,
    /// Its entries.
    pub(super) table: &'a DeTable<'i>,
}

impl<'a, 'i> TableRef<'a, 'i> {
    /// The value of `key`, if present.
    pub(super) fn get(&self, key: &str) -> Option<&'a Spanned<DeValue<'i>>> {
        let table: &'a DeTable<'i> = self.table;
        table
            .iter()
            .find(|(k, _)| {
                let name: &str = k.get_ref();
                name == key
            })
            .map(|(_, v)| v)
    }

    /// The dotted path of `key` in this table.
    pub(super) fn key_path(&self, key: &str) -> String {
        if self.path.is_empty() {
            key.to_string()
        } else {
            format!("{}.{key}", self.path)
        }
    }
}

/// A TOML type name with its article, for messages.
pub(super) fn type_name(v: &DeValue<'_>) -> &'static str {
    match v {
        DeValue::String(_) => "a string",
        DeValue::Integer(_) => "an integer",
        DeValue::Float(_) => "a float",
        DeValue::Boolean(_) => "a boolean",
        DeValue::Datetime(_) => "a date-time",
        DeValue::Array(_) => "an array",
        DeValue::Table(_) => "a table",
    }
}

/// A value as written in the file, strings quoted.
pub(super) fn shown(v: &DeValue<'_>) -> String {
    match v {
        DeValue::String(s) => format!("{s:?}"),
        DeValue::Integer(i) => i.to_string(),
        DeValue::Float(x) => x.as_str().to_string(),
        DeValue::Boolean(b) => b.to_string(),
        other => type_name(other).to_string(),
    }
}

pub(super) fn bad(v: &DeValue<'_>, reason: impl Into<String>) -> ProblemKind {
    ProblemKind::BadValue {
        value: shown(v),
        reason: reason.into(),
    }
}

fn wrong(v: &DeValue<'_>, expected: &'static str) -> ProblemKind {
    ProblemKind::WrongType {
        expected,
        found: type_name(v),
    }
}

/// A string value.
pub(super) fn string(v: &DeValue<'_>) -> Result<String, ProblemKind> {
    match v {
        DeValue::String(s) => Ok(s.to_string()),
        other => Err(wrong(other, "a string")),
    }
}

/// A boolean value.
pub(super) fn boolean(v: &DeValue<'_>) -> Result<bool, ProblemKind> {
    match v {
        DeValue::Boolean(b) => Ok(*b),
        other => Err(wrong(other, "true or false")),
    }
}

/// An integer within `range`; `use_what` completes "is not ...; use ..." when outside it.
pub(super) fn integer_in(
    v: &DeValue<'_>,
    range: std::ops::RangeInclusive<i64>,
    use_what: &str,
) -> Result<i64, ProblemKind> {
    let DeValue::Integer(i) = v else {
        return Err(wrong(v, "an integer"));
    };
    match i64::from_str_radix(i.as_str(), i.radix()) {
        Ok(n) if range.contains(&n) => Ok(n),
        _ => Err(bad(v, use_what)),
    }
}

/// A duration: text with a unit (`"20ms"`); a bare number is refused, showing the forms.
pub(super) fn duration(v: &DeValue<'_>) -> Result<Duration, ProblemKind> {
    let result = match v {
        DeValue::String(s) => parse_duration(s),
        DeValue::Integer(_) | DeValue::Float(_) => {
            let number = shown(v);
            // Only a number that would make sense with a unit gets one suggested.
            let plain = number.bytes().all(|b| b.is_ascii_digit() || b == b'.');
            Err(if plain {
                DurationError::NoUnit { text: number }
            } else {
                DurationError::Syntax { text: number }
            })
        }
        other => return Err(wrong(other, "a duration (\"20ms\", \"1.5s\")")),
    };
    result.map_err(|e| match e {
        DurationError::Syntax { .. } | DurationError::BadMillis { .. } => {
            bad(v, format!("is not a duration; use {ACCEPTED_FORMS}"))
        }
        DurationError::NoUnit { text } => bad(v, format!("has no unit: {}", no_unit_advice(&text))),
        DurationError::Overflow { .. } => bad(v, "is too long a duration"),
    })
}
