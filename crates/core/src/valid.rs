//! Configurations checked once: a [`Valid<T>`] can only be made by running `T`'s [`Check`], so
//! code that takes one never checks again, and code that must not run on an unchecked value
//! says so in its signature. It reads as `T` (`Deref`), prints and serialises as `T`, and
//! deserialising one runs the check (an invalid file is refused where it is read).

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// What a configuration must satisfy before anything runs on it.
pub trait Check {
    type Error;
    /// The configuration's own consistency; the error names the field and value at fault.
    fn check(&self) -> Result<(), Self::Error>;
}

/// A `T` whose [`Check`] passed.
#[derive(Clone, PartialEq)]
pub struct Valid<T>(T);

impl<T: Check> Valid<T> {
    /// Checks `value`.
    pub fn new(value: T) -> Result<Self, T::Error> {
        value.check()?;
        Ok(Valid(value))
    }
}

impl<T> Valid<T> {
    /// The configuration, to change it (and check it again with [`Valid::new`]).
    pub fn into_inner(self) -> T {
        self.0
    }

    /// A part of the configuration, checked with it: `pick` names a part (None: the part is not
    /// set) that `T`'s [`Check`] runs `U`'s check on, so the part is valid without a second
    /// check. Debug builds check it again to hold `T`'s check to that.
    pub fn part<U: Check + Clone>(&self, pick: impl FnOnce(&T) -> Option<&U>) -> Option<Valid<U>> {
        let u = pick(&self.0)?;
        debug_assert!(u.check().is_ok(), "a part of a checked configuration failed its own check");
        Some(Valid(u.clone()))
    }
}

impl<T> std::ops::Deref for Valid<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}

impl<T: std::fmt::Debug> std::fmt::Debug for Valid<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

impl<T: Serialize> Serialize for Valid<T> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.0.serialize(s)
    }
}

impl<'de, T> Deserialize<'de> for Valid<T>
where
    T: Deserialize<'de> + Check,
    T::Error: std::fmt::Display,
{
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Valid::new(T::deserialize(d)?).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    struct Rate {
        hz: f64,
    }

    impl Check for Rate {
        type Error = String;
        fn check(&self) -> Result<(), String> {
            if self.hz > 0.0 { Ok(()) } else { Err(format!("hz = {}: must be > 0", self.hz)) }
        }
    }

    #[test]
    fn only_a_checked_value_is_valid_and_it_reads_prints_and_serialises_as_itself() {
        assert_eq!(Valid::new(Rate { hz: 0.0 }).unwrap_err(), "hz = 0: must be > 0");
        let v = Valid::new(Rate { hz: 2.0 }).unwrap();
        assert_eq!(v.hz, 2.0);
        assert_eq!(format!("{v:?}"), format!("{:?}", Rate { hz: 2.0 }));
        assert_eq!(serde_json::to_string(&v).unwrap(), r#"{"hz":2.0}"#);
        let back: Valid<Rate> = serde_json::from_str(r#"{"hz":2.0}"#).unwrap();
        assert_eq!(back, v);
        let e = serde_json::from_str::<Valid<Rate>>(r#"{"hz":-1.0}"#).unwrap_err().to_string();
        assert!(e.contains("hz = -1: must be > 0"), "{e}");
        assert_eq!(v.into_inner(), Rate { hz: 2.0 });
    }

    #[derive(Clone, Debug, PartialEq)]
    struct Pair {
        first: Rate,
        second: Option<Rate>,
    }

    impl Check for Pair {
        type Error = String;
        fn check(&self) -> Result<(), String> {
            self.first.check()?;
            self.second.as_ref().map_or(Ok(()), Rate::check)
        }
    }

    #[test]
    fn a_part_of_a_checked_value_is_valid_and_an_unset_part_is_none() {
        let v = Valid::new(Pair { first: Rate { hz: 1.0 }, second: None }).unwrap();
        assert_eq!(v.part(|p| Some(&p.first)).unwrap().hz, 1.0);
        assert!(v.part(|p| p.second.as_ref()).is_none());
        assert!(Valid::new(Pair { first: Rate { hz: 1.0 }, second: Some(Rate { hz: -1.0 }) }).is_err());
    }
}
