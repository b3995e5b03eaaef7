//! Register-map models of the supported devices (SPEC "Device profiles").
