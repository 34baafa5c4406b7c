//! The environment variables that override a scene's executor, for experiments on a machine
//! without editing a scene: `INCISE_THREADS` (a thread count, 1 to
//! [`incise_sim::config::MAX_THREADS`]) and `INCISE_LINGER_US` (microseconds an idle worker
//! spins before it sleeps; 0 sleeps at once). They are read here, where the programs load their
//! scenes, and never by the physics crates: a simulation built by a library user does what its
//! configuration says.

use incise_fem::Idle;
use incise_sim::config::{ExecSpec, MAX_THREADS};
use std::time::Duration;

/// The thread count's variable.
pub const THREADS: &str = "INCISE_THREADS";

/// The idle workers' spin's variable.
pub const LINGER_US: &str = "INCISE_LINGER_US";

/// An environment variable that does not hold what it should.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("the environment variable {variable}={value:?} is not {expected}")]
pub struct EnvironmentError {
    /// The variable.
    pub variable: &'static str,
    /// What it holds.
    pub value: String,
    /// What it should hold.
    pub expected: String,
}

/// `spec` with what the environment sets in its place.
///
/// # Errors
/// If a variable is set to something other than what it takes.
pub fn exec_from_environment(spec: ExecSpec) -> Result<ExecSpec, EnvironmentError> {
    let read = |variable: &'static str| std::env::var(variable).ok();
    exec_from(spec, read(THREADS).as_deref(), read(LINGER_US).as_deref())
}

/// `spec` with `threads` and `linger_us` (the variables' values, where set) in its place.
fn exec_from(
    spec: ExecSpec,
    threads: Option<&str>,
    linger_us: Option<&str>,
) -> Result<ExecSpec, EnvironmentError> {
    let threads = threads
        .map(|value| {
            value.trim().parse::<usize>().ok().filter(|n| (1..=MAX_THREADS).contains(n)).ok_or_else(
                || EnvironmentError {
                    variable: THREADS,
                    value: value.to_owned(),
                    expected: format!("a thread count from 1 to {MAX_THREADS}"),
                },
            )
        })
        .transpose()?;
    let idle = linger_us
        .map(|value| {
            let us = value.trim().parse::<u64>().map_err(|_| EnvironmentError {
                variable: LINGER_US,
                value: value.to_owned(),
                expected: "a whole number of microseconds (0: idle workers sleep)".to_owned(),
            })?;
            Ok(if us == 0 { Idle::Sleep } else { Idle::Spin(Duration::from_micros(us)) })
        })
        .transpose()?;
    Ok(ExecSpec { threads: threads.or(spec.threads), idle: idle.or(spec.idle) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_variables_override_the_scene_and_bad_ones_are_named() {
        let scene = ExecSpec { threads: Some(2), idle: Some(Idle::Sleep) };
        assert_eq!(exec_from(scene, None, None), Ok(scene));
        let set = exec_from(scene, Some("1"), Some("250")).unwrap();
        assert_eq!(set.threads, Some(1));
        assert_eq!(set.idle, Some(Idle::Spin(Duration::from_micros(250))));
        assert_eq!(
            exec_from(ExecSpec::default(), None, Some("0")).unwrap().idle,
            Some(Idle::Sleep)
        );
        for (threads, linger, variable) in [
            (Some("two"), None, THREADS),
            (Some("0"), None, THREADS),
            (Some("257"), None, THREADS),
            (None, Some("-1"), LINGER_US),
            (None, Some("0.5"), LINGER_US),
        ] {
            let e = exec_from(scene, threads, linger).unwrap_err();
            assert_eq!(e.variable, variable);
            assert!(e.to_string().contains(variable), "{e}");
        }
    }
}
