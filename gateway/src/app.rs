//! Wiring a config into running tasks.
