//! Rayleigh damping, `C = αM + βK`.

/// Rayleigh damping `C = αM + βK`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Rayleigh {
    /// Mass-proportional coefficient α (1/s).
    pub alpha: f64,
    /// Stiffness-proportional coefficient β (s).
    pub beta: f64,
}
