//! Fuzz-style checks of the scene decoder: no text makes [`SceneConfig::from_toml`] panic, every
//! error names a line that exists, and a scene it accepts builds and steps (or is refused by
//! [`Simulation::new`]) without a panic.
//!
//! Inputs come from a deterministic generator (same cases every run): the committed scene files
//! with bytes changed, cut short, lines deleted, duplicated or swapped, and numbers or strings
//! replaced by extreme or wrong ones. A few hundred cases per file.

use crate::{SceneConfig, SceneError, Simulation, StepInputs};

const SCENES: [(&str, &str); 6] = [
    ("b1.toml", include_str!("../../../deploy/scenes/b1.toml")),
    ("c_10x1x1.toml", include_str!("../../../deploy/scenes/c_10x1x1.toml")),
    ("liver_13k.toml", include_str!("../../../deploy/scenes/liver_13k.toml")),
    ("liver_auto.toml", include_str!("../../../deploy/scenes/liver_auto.toml")),
    ("liver_tensor_mass.toml", include_str!("../../../deploy/scenes/liver_tensor_mass.toml")),
    ("cylinder_mesh.toml", include_str!("../../../deploy/scenes/cylinder_mesh.toml")),
];

const NUMBERS: [&str; 14] = [
    "0",
    "-1",
    "1e308",
    "-1e308",
    "nan",
    "inf",
    "-inf",
    "-0.0",
    "1e-320",
    "4096",
    "99999999999",
    "0.5",
    "[]",
    "\"x\"",
];

const WORDS: [&str; 12] = [
    "\"\"",
    "\"static\"",
    "\"explicit\"",
    "\"auto\"",
    "\"tensor-mass\"",
    "\"cholesky\"",
    "\"consistent\"",
    "\"x\"",
    "\"mm\"",
    "\"sleep\"",
    "1",
    "[1, 2]",
];

/// xorshift64*: a fixed stream of case choices.
struct Cases(u64);

impl Cases {
    fn next(&mut self, n: usize) -> usize {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 33) as usize % n.max(1)
    }
}

/// One mutation of `text`.
fn mutate(text: &str, cases: &mut Cases) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    match cases.next(7) {
        0 => {
            let mut bytes = text.as_bytes().to_vec();
            for _ in 0..=cases.next(3) {
                let at = cases.next(bytes.len());
                bytes[at] = cases.next(256) as u8;
            }
            return String::from_utf8_lossy(&bytes).into_owned();
        }
        1 => return text[..text.floor_char_boundary(cases.next(text.len()))].to_owned(),
        2 => {
            lines.remove(cases.next(lines.len()));
        }
        3 => {
            let at = cases.next(lines.len());
            lines.insert(at, lines[at].clone());
        }
        4 => {
            let (a, b) = (cases.next(lines.len()), cases.next(lines.len()));
            lines.swap(a, b);
        }
        _ => {
            // A value replaced: a number by an extreme one, a string by another word.
            let candidates: Vec<usize> =
                (0..lines.len()).filter(|&i| lines[i].contains(" = ")).collect();
            if let Some(&i) = candidates.get(cases.next(candidates.len())) {
                let (key, value) = lines[i].split_once(" = ").expect("filtered on it");
                let new = if value.starts_with('"') {
                    WORDS[cases.next(WORDS.len())]
                } else {
                    NUMBERS[cases.next(NUMBERS.len())]
                };
                lines[i] = format!("{key} = {new}");
            }
        }
    }
    lines.join("\n")
}

/// Builds and steps a procedural scene small enough to build quickly; the result is not
/// checked, only that it returns.
fn build_small(config: &SceneConfig) {
    let Some(volume) = config.procedural_volume() else { return };
    let auto = matches!(
        &config.model,
        crate::config::Model::Hexahedra(crate::config::HexSpec {
            level: crate::config::Level::Auto(_),
            ..
        })
    );
    if volume.dims().iter().product::<usize>() > 2_000 || auto {
        return;
    }
    if let Ok(mut sim) = Simulation::new(config, &volume, "fuzz.toml") {
        for _ in 0..3 {
            let _ = sim.step(&StepInputs::default());
        }
    }
}

#[test]
fn mutated_scene_files_give_errors_with_real_lines_never_panics() {
    let mut cases = Cases(0x9e37_79b9_7f4a_7c15);
    let (mut accepted, mut refused) = (0, 0);
    for (name, text) in SCENES {
        for _ in 0..300 {
            let mutated = mutate(text, &mut cases);
            let lines = mutated.lines().count().max(1);
            match SceneConfig::from_toml(&mutated, name) {
                Ok(config) => {
                    accepted += 1;
                    build_small(&config);
                }
                Err(e) => {
                    refused += 1;
                    let line = match &e {
                        SceneError::Parse { line, .. } | SceneError::Invalid { line, .. } => *line,
                        SceneError::Build { .. } => unreachable!("parsing does not build"),
                    };
                    assert!(
                        (1..=lines + 1).contains(&line),
                        "{e}: line {line} of {lines}\n--- scene:\n{mutated}"
                    );
                    assert!(e.to_string().starts_with(&format!("{name}:{line}: ")), "{e}");
                }
            }
        }
    }
    // Both outcomes occur, so both paths were exercised.
    assert!(accepted > 100 && refused > 300, "{accepted} accepted, {refused} refused");
}
