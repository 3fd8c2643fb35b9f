//! Named choices: the closed sets of options a user picks by name (a solver, a matching
//! method, a preset). One table per enum gives every value's spelling and help line; from
//! it come [`std::str::FromStr`] and [`std::fmt::Display`] (what the Python package and
//! the manifests use) and, with the `cli` feature, `clap::ValueEnum` (what the CLI
//! parses). The CLI and the bindings therefore accept exactly the same words, and no
//! front end keeps a copy of an enum to map by hand.

/// A value of a closed set of named options.
pub trait Choice: Sized + Copy + 'static {
    /// What is being chosen, for messages ("solver").
    const WHAT: &'static str;
    /// Every value in the table's order.
    const ALL: &'static [Self];
    /// This value's spelling.
    fn name(self) -> &'static str;
    /// This value's one-line help.
    fn help(self) -> &'static str;

    /// Every spelling, comma-separated, for messages.
    fn spellings() -> String {
        Self::ALL
            .iter()
            .map(|v| v.name())
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The value spelled `text` (exactly, as the CLI parses it).
    fn parse_choice(text: &str) -> crate::Result<Self> {
        Self::ALL
            .iter()
            .copied()
            .find(|v| v.name() == text)
            .ok_or_else(|| crate::Error::NotFound {
                what: Self::WHAT.into(),
                name: text.to_string(),
                available: Self::spellings(),
            })
    }
}

/// Implements [`Choice`], `FromStr`, `Display` and (feature `cli`) `clap::ValueEnum` for a
/// unit enum from one table: `Enum, "what" { Variant = "spelling" "help", ... }`.
macro_rules! named_choices {
    ($ty:ident, $what:literal { $($variant:ident = $name:literal $help:literal),+ $(,)? }) => {
        impl $crate::choice::Choice for $ty {
            const WHAT: &'static str = $what;
            const ALL: &'static [Self] = &[$($ty::$variant),+];
            fn name(self) -> &'static str {
                match self {
                    $($ty::$variant => $name),+
                }
            }
            fn help(self) -> &'static str {
                match self {
                    $($ty::$variant => $help),+
                }
            }
        }

        impl std::str::FromStr for $ty {
            type Err = $crate::Error;
            fn from_str(text: &str) -> $crate::Result<Self> {
                <$ty as $crate::choice::Choice>::parse_choice(text)
            }
        }

        impl std::fmt::Display for $ty {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str($crate::choice::Choice::name(*self))
            }
        }

        #[cfg(feature = "cli")]
        impl clap::ValueEnum for $ty {
            fn value_variants<'a>() -> &'a [Self] {
                <$ty as $crate::choice::Choice>::ALL
            }
            fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
                use $crate::choice::Choice;
                let value = clap::builder::PossibleValue::new(self.name());
                Some(match self.help() {
                    "" => value,
                    help => value.help(help),
                })
            }
        }
    };
}
pub(crate) use named_choices;

#[cfg(test)]
mod tests {
    use super::Choice;
    use crate::demux::Solver;
    use crate::Error;

    #[test]
    fn every_spelling_parses_back_and_unknown_ones_list_the_choices() {
        for &solver in Solver::ALL {
            assert_eq!(solver.name().parse::<Solver>().unwrap(), solver);
            assert_eq!(solver.to_string(), solver.name());
        }
        match "fastest".parse::<Solver>() {
            Err(Error::NotFound {
                what, available, ..
            }) => {
                assert_eq!(what, "solver");
                assert!(available.contains("exact") && available.contains("lsqr"));
            }
            other => panic!("{other:?}"),
        }
    }
}
