//! A cursor reader and writer that own every length check, so no decoder indexes a slice directly.
