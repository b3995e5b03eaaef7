//! The device profiles by name: the one list a new profile is added to. [`Registered`] itself
//! lives with [`DeviceProfile`] (the profiles import it, this list imports the profiles: no
//! circle).

use super::{altivar, ksvario, DeviceProfile, Registered};

/// Every device profile. A new profile is one module of [`crate::profiles`] and one line here.
pub const PROFILES: &[Registered] = &[altivar::REGISTERED, ksvario::REGISTERED];

/// The profile registered under `name` (ASCII case ignored).
pub fn lookup(name: &str) -> Option<&'static Registered> {
    PROFILES.iter().find(|p| p.name.eq_ignore_ascii_case(name))
}

/// The profile registered under `name`, built.
pub fn by_name(name: &str) -> Option<DeviceProfile> {
    lookup(name).map(|p| (p.build)())
}

/// The registered names, in the registry's order.
pub fn names() -> impl Iterator<Item = &'static str> {
    PROFILES.iter().map(|p| p.name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_entry_builds_its_own_profile() {
        for entry in PROFILES {
            let profile = (entry.build)();
            assert_eq!(profile.name, entry.name);
            assert_eq!(profile.limits, entry.limits);
            assert_eq!(by_name(entry.name), Some(profile));
        }
        assert_eq!(
            lookup("Altivar71").map(|p| p.name),
            Some("altivar71"),
            "case is ignored"
        );
        assert!(
            lookup("generic").is_none(),
            "generic is built from a tag list"
        );
    }

    #[test]
    fn capabilities_are_data() {
        let altivar = lookup("altivar71").expect("registered");
        let scanner = altivar.scanner.expect("the Altivar has a scanner");
        assert_eq!(
            (scanner.inputs_at, scanner.outputs_at, scanner.max_words),
            (12741, 12761, 8)
        );
        assert!(lookup("ksvario").and_then(|p| p.scanner).is_none());
        assert_eq!(names().collect::<Vec<_>>(), ["altivar71", "ksvario"]);
    }
}
