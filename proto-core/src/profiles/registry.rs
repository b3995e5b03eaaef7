//! The device profiles by name: the one list a new profile is added to.

use super::{altivar, ksvario, DeviceProfile, RequestLimits};

/// One known device type.
#[derive(Clone, Copy, Debug)]
pub struct Registered {
    /// The name a configuration uses (`profile = "altivar71"`).
    pub name: &'static str,
    /// The manual the profile follows, for messages (e.g. on request limits).
    pub source: &'static str,
    /// Builds the profile.
    pub build: fn() -> DeviceProfile,
    /// The device's request limits (the same as `build().limits`, without building the tags).
    pub limits: RequestLimits,
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_entry_builds_its_own_profile() {
        for entry in PROFILES {
            let profile = (entry.build)();
            assert_eq!(profile.name, entry.name);
            assert_eq!(profile.limits, entry.limits);
            assert_eq!(by_name(entry.name).map(|p| p.kind), Some(profile.kind));
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
}
