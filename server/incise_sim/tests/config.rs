//! The scene decoder alone: what a scene file becomes, and the key and line of every error
//! (scenes built and stepped, and the committed files, are tested in `tests/tests/scenes.rs`).

use incise_fem::Formulation;
use incise_fem::ode::{MassMatrix, Rayleigh};
use incise_sim::config::{
    AutoLevel, ElementKind, HexSpec, ImplicitSolver, Integrator, Level, Model, StaticSolver,
    TetIntegrator,
};
use incise_sim::{SceneConfig, SceneError};

fn error(text: &str) -> SceneError {
    SceneConfig::from_toml(text, "bad.toml").unwrap_err()
}

/// A 2 × 2 × 2 block hanging from its top face: the smallest valid scene, shared with the cross-crate scene tests.
const GOOD: &str = include_str!("data/minimal_block.toml");

#[test]
fn scene_errors_name_the_key_and_line() {
    assert!(SceneConfig::from_toml(GOOD, "good.toml").is_ok());
    let e = error(&GOOD.replace("dt = 0.001", "dt = -0.001"));
    assert!(
        e.to_string().starts_with("bad.toml:13:") && e.to_string().contains("integrator.dt"),
        "{e}"
    );
    let e = error(&GOOD.replace("density = 1000.0", "density = 1000.0\ndensty = 3.0"));
    assert!(e.to_string().starts_with("bad.toml:11:") && e.to_string().contains("densty"), "{e}");
    let e = error(&GOOD.replace("poisson_ratio = 0.3", "poisson_ratio = 0.5"));
    assert!(
        e.to_string().contains("bad.toml:9:")
            && e.to_string().contains("materials[0].poisson_ratio"),
        "{e}"
    );
    let e = error(&GOOD.replace("plane = \"z\"", "plane = \"w\""));
    assert!(
        e.to_string().contains("bad.toml:15:") && e.to_string().contains("fixed[0].plane"),
        "{e}"
    );
    let e = error(&GOOD.replace("kind = \"implicit-euler\"", "kind = \"rk4\""));
    assert!(e.to_string().contains("integrator.kind") && e.to_string().contains("rk4"), "{e}");
    let e = error("name = ");
    assert!(matches!(e, SceneError::Parse { line: 1, .. }), "{e}");
}

/// `(line, key)` of an `Invalid` error, or of a `Parse` error (key empty).
fn where_(e: &SceneError) -> (usize, String) {
    match e {
        SceneError::Invalid { line, key, .. } => (*line, key.clone()),
        SceneError::Parse { line, .. } => (*line, String::new()),
        SceneError::Build { .. } => (0, String::new()),
    }
}

#[test]
fn keys_that_contradict_their_region_or_integrator_are_refused_with_their_line() {
    let cases: Vec<(String, usize, &str)> = vec![
        // A procedural block with a file's keys, and a file with a block's.
        (GOOD.replace("voxels = [2, 2, 2]", "voxels = [2, 2, 2]\nstride = [2, 2, 2]"), 6, "volume.stride"),
        (GOOD.replace("voxels = [2, 2, 2]", "voxels = [2, 2, 2]\nlabels = [1]"), 6, "volume.labels"),
        (
            GOOD.replace("procedural = \"block\"", "file = \"liver.nii.gz\""),
            4,
            "volume.size_m",
        ),
        // A [volume] with neither: the error points at its header.
        (
            GOOD.replace("procedural = \"block\"\nsize_m = [0.1, 0.1, 0.1]\nvoxels = [2, 2, 2]\n", ""),
            2,
            "volume",
        ),
        // Fixed regions: a plane with a box corner, a box with a plane's value, half a box, a
        // value with no plane, a label with a plane, and an empty entry (its header's line).
        (GOOD.replace("value = 0.1", "value = 0.1\nmin = [0.0, 0.0, 0.0]"), 17, "fixed[0].min"),
        (
            GOOD.replace("plane = \"z\"\nvalue = 0.1", "min = [0.0, 0.0, 0.0]\nmax = [1.0, 1.0, 0.0]\nvalue = 0.1"),
            17,
            "fixed[0].value",
        ),
        (GOOD.replace("plane = \"z\"\nvalue = 0.1", "min = [0.0, 0.0, 0.0]"), 15, "fixed[0].min"),
        (GOOD.replace("plane = \"z\"\n", ""), 15, "fixed[0].value"),
        (GOOD.replace("value = 0.1", "label = 1"), 15, "fixed[0].plane"),
        (GOOD.replace("plane = \"z\"\nvalue = 0.1\n", ""), 14, "fixed[0]"),
        // Per-material damping would be dropped: refused, naming the scene-wide keys.
        (GOOD.replace("density = 1000.0", "density = 1000.0\nrayleigh_mass = 0.1"), 11, "materials[0].rayleigh_mass"),
        // The explicit integrator has no linear solve and no stiffness damping.
        (
            GOOD.replace("kind = \"implicit-euler\"", "kind = \"explicit\"\nsolver = \"cholesky\""),
            13,
            "integrator.solver",
        ),
        (
            GOOD.replace("kind = \"implicit-euler\"", "kind = \"explicit\"\ncg_tolerance = 1e-8"),
            13,
            "integrator.cg_tolerance",
        ),
        (
            GOOD.replace("kind = \"implicit-euler\"", "kind = \"explicit\"\nrayleigh_beta = 0.01"),
            13,
            "integrator.rayleigh_beta",
        ),
        // The direct solver solves exactly: a CG tolerance would be ignored.
        (
            GOOD.replace("dt = 0.001", "dt = 0.001\nsolver = \"cholesky\"\ncg_tolerance = 1e-8"),
            15,
            "integrator.cg_tolerance",
        ),
        // An empty list of materials, at its line.
        (
            GOOD.replace("[[materials]]\nlabel = 1\nyoungs_modulus = 1000.0\npoisson_ratio = 0.3\ndensity = 1000.0\n", "")
                .replace("name = \"t\"", "name = \"t\"\nmaterials = []"),
            2,
            "materials",
        ),
        // No materials at all: reported at line 1, as serde reports a missing top-level key.
        (
            GOOD.replace("[[materials]]\nlabel = 1\nyoungs_modulus = 1000.0\npoisson_ratio = 0.3\ndensity = 1000.0\n", ""),
            1,
            "materials",
        ),
    ];
    for (text, line, key) in cases {
        let e = error(&text);
        assert_eq!(where_(&e), (line, key.to_owned()), "{e}\n--- scene:\n{text}");
        assert!(e.to_string().starts_with(&format!("bad.toml:{line}: `{key}`")), "{e}");
    }
    // Explicit with mass damping only, and β = 0 written out, stay valid.
    let explicit = GOOD.replace(
        "kind = \"implicit-euler\"",
        "kind = \"explicit\"\nrayleigh_alpha = 2.0\nrayleigh_beta = 0.0",
    );
    assert!(SceneConfig::from_toml(&explicit, "ok.toml").is_ok());
}

#[test]
fn auto_model_keys_are_checked() {
    let auto =
        GOOD.replace("[integrator]", "[model]\nkind = \"auto\"\nmax_error = 0.05\n[integrator]");
    assert!(matches!(
        SceneConfig::from_toml(&auto, "good.toml").unwrap().model,
        Model::Hexahedra(HexSpec {
            level: Level::Auto(AutoLevel { max_error: 0.05, max_level: 3, any_element: true }),
            formulation: Formulation::Corotational,
            element: ElementKind::Condensed,
            ..
        })
    ));
    let e = error(&format!("level = 1\n{auto}"));
    assert!(e.to_string().starts_with("bad.toml:1:") && e.to_string().contains("`level`"), "{e}");
    let e = error(&auto.replace("max_error = 0.05", "max_error = 5.0"));
    assert!(e.to_string().contains("model.max_error"), "{e}");
    let e = error(&auto.replace("kind = \"auto\"", "kind = \"corotational\""));
    assert!(e.to_string().contains("model.max_error") && e.to_string().contains("auto"), "{e}");
    let e = error(&auto.replace("max_error = 0.05", "max_level = 9"));
    assert!(e.to_string().contains("model.max_level"), "{e}");
    // An element kind given to an auto scene is kept: the calibration then chooses only the
    // level.
    assert!(matches!(
        SceneConfig::from_toml(
            &auto.replace("max_error", "element = \"composite\"\nmax_error"),
            "g.toml"
        )
        .unwrap()
        .model,
        Model::Hexahedra(HexSpec {
            level: Level::Auto(AutoLevel { any_element: false, .. }),
            element: ElementKind::Composite,
            ..
        })
    ));
}

#[test]
fn the_element_kind_is_a_scene_key() {
    for kind in ["condensed", "composite", "incompatible"] {
        let text = GOOD.replace(
            "[integrator]",
            &format!("[model]\nkind = \"linear\"\nelement = \"{kind}\"\n[integrator]"),
        );
        let Model::Hexahedra(hex) = SceneConfig::from_toml(&text, "g.toml").unwrap().model else {
            panic!("hexahedra")
        };
        assert_eq!(hex.element.name(), kind);
        assert_eq!(hex.formulation, Formulation::Linear);
    }
    let e = error(&GOOD.replace(
        "[integrator]",
        "[model]\nkind = \"corotational\"\nelement = \"quadratic\"\n[integrator]",
    ));
    let text = e.to_string();
    assert!(text.starts_with("bad.toml:") && text.contains("model.element"), "{e}");
    assert!(text.contains("quadratic") && text.contains("incompatible"), "{e}");
    let e = error(&tensor_mass_scene("element = \"composite\"\n", "1e-4"));
    assert!(e.to_string().contains("model.element") && e.to_string().contains("tetrahedra"), "{e}");
}

/// `GOOD` as a tensor-mass scene (48 tetrahedra on 2 × 2 × 2 voxels).
fn tensor_mass_scene(model_keys: &str, dt: &str) -> String {
    GOOD.replace(
        "[integrator]\nkind = \"implicit-euler\"\ndt = 0.001",
        &format!("[model]\nkind = \"tensor-mass\"\n{model_keys}[integrator]\nkind = \"explicit\"\ndt = {dt}"),
    )
}

#[test]
fn tensor_mass_keys_are_checked() {
    let ok = tensor_mass_scene("elasticity = \"svk\"\nincompressibility = 1e5\n", "1e-4");
    let config = SceneConfig::from_toml(&ok, "tm.toml").unwrap();
    let Model::TensorMass(tm) = &config.model else { panic!("a tensor-mass model") };
    assert_eq!(tm.incompressibility, Some(1e5));
    assert_eq!(tm.integrator, TetIntegrator::Explicit { dt: 1e-4, rayleigh_alpha: 0.0 });
    let e = error(&tensor_mass_scene("elasticity = \"neo-hookean\"\n", "1e-4"));
    assert!(
        e.to_string().contains("model.elasticity") && e.to_string().contains("neo-hookean"),
        "{e}"
    );
    let implicit =
        tensor_mass_scene("", "1e-4").replace("kind = \"explicit\"", "kind = \"implicit-euler\"");
    assert!(SceneConfig::from_toml(&implicit, "tm.toml").is_ok());
    let e = error(&implicit.replace("kind = \"implicit-euler\"", "kind = \"static\""));
    assert!(
        e.to_string().contains("integrator.kind") && e.to_string().contains("hexahedra"),
        "{e}"
    );
    let e = error(&implicit.replace("dt = 1e-4", "dt = 1e-4\nsolver = \"cholesky-cg\""));
    assert!(e.to_string().contains("integrator.solver"), "{e}");
    let e = error(&implicit.replace("dt = 1e-4", "dt = 1e-4\nmass = \"consistent\""));
    assert!(e.to_string().contains("integrator.mass"), "{e}");
    let e = error(&tensor_mass_scene("adaptive_threshold = -1.0\n", "1e-4"));
    assert!(e.to_string().contains("model.adaptive_threshold"), "{e}");
    let e = error(&tensor_mass_scene("fibre_ratio = 2.0\n", "1e-4"));
    assert!(
        e.to_string().contains("model.fibre_ratio") && e.to_string().contains("model.fibre"),
        "{e}"
    );
    let e = error(&GOOD.replace(
        "[integrator]",
        "[model]\nkind = \"corotational\"\nincompressibility = 1e5\n[integrator]",
    ));
    assert!(
        e.to_string().contains("model.incompressibility") && e.to_string().contains("tensor-mass"),
        "{e}"
    );
}

/// GOOD with its plane support replaced by `fixed`.
fn held_by(fixed: &str) -> String {
    GOOD.replace("[[fixed]]\nplane = \"z\"\nvalue = 0.1\n", &format!("[[fixed]]\n{fixed}\n"))
}

#[test]
fn label_holds_are_checked() {
    let e = error(&held_by("label = 7"));
    assert!(
        e.to_string().contains("fixed[0].label") && e.to_string().contains("is 7"),
        "names the key and the label: {e}"
    );
    assert!(e.to_string().starts_with("bad.toml:15:"), "and the line: {e}");
    let e = error(&held_by("label = 1\nplane = \"z\"\nvalue = 0.1"));
    assert!(
        e.to_string().starts_with("bad.toml:16: `fixed[0].plane` cannot be given with `label`"),
        "{e}"
    );
}

#[test]
fn the_mass_matrix_is_a_scene_key() {
    let consistent = GOOD.replace("dt = 0.001", "dt = 0.001\nmass = \"consistent\"");
    let config = SceneConfig::from_toml(&consistent, "t.toml").unwrap();
    assert!(matches!(
        config.model,
        Model::Hexahedra(HexSpec {
            integrator: Integrator::ImplicitEuler { mass: MassMatrix::Consistent, .. },
            ..
        })
    ));
    let e = error(&GOOD.replace("dt = 0.001", "dt = 0.001\nmass = \"heavy\""));
    assert!(e.to_string().contains("integrator.mass") && e.to_string().contains("heavy"), "{e}");
    let e = error(
        &consistent
            .replace("kind = \"implicit-euler\"\ndt = 0.001", "kind = \"explicit\"\ndt = 0.0001"),
    );
    assert!(e.to_string().contains("integrator.mass") && e.to_string().contains("diagonal"), "{e}");
}

#[test]
fn non_finite_numbers_and_repeated_labels_are_refused() {
    // TOML has nan and inf: each is refused with its key and line.
    let e = error(&GOOD.replace("value = 0.1", "value = nan"));
    assert!(
        e.to_string().contains("bad.toml:16:") && e.to_string().contains("fixed[0].value"),
        "{e}"
    );
    let e = error(&format!("gravity = [0.0, 0.0, -inf]\n{GOOD}"));
    assert!(e.to_string().contains("bad.toml:1:") && e.to_string().contains("gravity"), "{e}");
    let load = "[[loads]]\ncentre = [0.0, 0.0, 0.0]\nradius = 0.01\nforce = [1.0, nan, 0.0]\n";
    let e = error(&format!("{GOOD}{load}"));
    assert!(
        e.to_string().contains("bad.toml:20:") && e.to_string().contains("loads[0].force"),
        "{e}"
    );
    let boxed =
        GOOD.replace("plane = \"z\"\nvalue = 0.1", "min = [0.0, 0.0, 0.0]\nmax = [inf, 1.0, 1.0]");
    let e = error(&boxed);
    assert!(e.to_string().contains("fixed[0].max"), "{e}");
    // One label, one material.
    let twice = "[[materials]]\nlabel = 1\nyoungs_modulus = 2000.0\npoisson_ratio = 0.3\ndensity = 1000.0\n";
    let e = error(&format!("{GOOD}{twice}"));
    assert!(
        e.to_string().contains("bad.toml:18:") && e.to_string().contains("materials[1].label"),
        "{e}"
    );
}

#[test]
fn each_integrator_carries_only_its_own_settings() {
    let integrator = |keys: &str| {
        let text = GOOD.replace("kind = \"implicit-euler\"\ndt = 0.001", keys);
        match SceneConfig::from_toml(&text, "t.toml").unwrap().model {
            Model::Hexahedra(hex) => hex.integrator,
            Model::TensorMass(_) => unreachable!("GOOD is hexahedral"),
        }
    };
    assert_eq!(
        integrator("kind = \"implicit-euler\"\ndt = 0.001\nrayleigh_beta = 0.01"),
        Integrator::ImplicitEuler {
            dt: 0.001,
            solver: ImplicitSolver::JacobiCg { cg_tolerance: 1e-6 },
            mass: MassMatrix::Lumped,
            damping: Rayleigh { alpha: 0.0, beta: 0.01 },
        }
    );
    assert!(matches!(
        integrator("kind = \"implicit-euler\"\ndt = 0.001\nsolver = \"cholesky\""),
        Integrator::ImplicitEuler { solver: ImplicitSolver::Cholesky, .. }
    ));
    assert_eq!(
        integrator("kind = \"explicit\"\ndt = 0.0001\nrayleigh_alpha = 3.0"),
        Integrator::Explicit { dt: 1e-4, rayleigh_alpha: 3.0 }
    );
    // A static scene's "cholesky" and "cholesky-cg" both precondition Newton's CG.
    for solver in ["cholesky", "cholesky-cg"] {
        assert_eq!(
            integrator(&format!(
                "kind = \"static\"\ndt = 0.001\ncg_tolerance = 1e-9\nsolver = \"{solver}\"\nrayleigh_alpha = 2.0"
            )),
            Integrator::Static {
                dt: 0.001,
                tolerance: 1e-9,
                solver: StaticSolver::CholeskyCg,
                damping: Rayleigh { alpha: 2.0, beta: 0.0 },
            }
        );
    }
}

/// `GOOD` on a label file with `keys` in its `[volume]`, and materials for labels 1, 2 and 3.
fn label_file(keys: &str) -> String {
    let material = |label: u16| {
        format!(
            "[[materials]]\nlabel = {label}\nyoungs_modulus = 1000.0\npoisson_ratio = 0.3\ndensity = 1000.0\n"
        )
    };
    GOOD.replace(
        "procedural = \"block\"\nsize_m = [0.1, 0.1, 0.1]\nvoxels = [2, 2, 2]\n",
        &format!("file = \"organ.nii.gz\"\n{keys}\n"),
    )
    .replace("[integrator]", &format!("{}{}[integrator]", material(2), material(3)))
}

#[test]
fn labels_are_merged_and_kept_as_the_scene_says() {
    let labels = |keys: &str| {
        let config = SceneConfig::from_toml(&label_file(keys), "t.toml").unwrap();
        match config.volume() {
            Some(incise_sim::config::VolumeSpec::File { labels, .. }) => labels.clone(),
            other => panic!("{other:?}"),
        }
    };
    // Neither key: the file's labels as they are.
    let all = labels("");
    assert_eq!(all, incise_grid::LabelFilter::all());
    assert_eq!((all.apply(7), all.apply(2)), (7, 2));
    let f = labels("merge = [[7, 2], [8, 3]]\nkeep = [2, 3]");
    assert_eq!([f.apply(7), f.apply(8), f.apply(2), f.apply(1), f.apply(3)], [2, 3, 2, 0, 3]);
    // `labels` is the older name of `keep`.
    assert_eq!(labels("labels = [1, 2]"), labels("keep = [1, 2]"));
    // The liver fixture's clean-up, written out.
    assert_eq!(labels("merge = [[84, 2]]"), incise_grid::LabelFilter::all().merge(84, 2));

    // The file is on line 3, the keys from line 4.
    let cases = [
        ("merge = [[7, 9]]", 4, "volume.merge[0]", "no `[[materials]]`"),
        ("merge = [[2, 2]]", 4, "volume.merge[0]", "into itself"),
        ("merge = [[7, 2], [7, 3]]", 4, "volume.merge[1]", "again"),
        ("merge = [[7, 2], [2, 3]]", 4, "volume.merge[1]", "chain"),
        ("merge = [[0, 2]]", 4, "volume.merge[0]", "1..=65535"),
        ("keep = [1, 9]", 4, "volume.keep", "keeps 9"),
        ("keep = []", 4, "volume.keep", "keeps no label"),
        ("labels = [9]", 4, "volume.labels", "keeps 9"),
        ("merge = [[7, 2]]\nkeep = [7]", 5, "volume.keep", "merges into 2"),
        ("keep = [1]\nlabels = [1]", 5, "volume.labels", "older name"),
    ];
    for (keys, line, key, what) in cases {
        let e = error(&label_file(keys));
        assert_eq!(where_(&e), (line, key.to_owned()), "{keys}: {e}");
        assert!(e.to_string().contains(what), "{keys}: {e}");
    }
    // A procedural block has no labels to merge or keep.
    let e = error(&GOOD.replace("voxels = [2, 2, 2]", "voxels = [2, 2, 2]\nmerge = [[2, 1]]"));
    assert_eq!(where_(&e), (6, "volume.merge".to_owned()), "{e}");
}

/// `GOOD` as a tensor-mass scene on the mesh file `organ.vtu` with `keys` in its `[volume]`.
fn mesh_scene(keys: &str) -> String {
    tensor_mass_scene("", "1e-4").replace(
        "procedural = \"block\"\nsize_m = [0.1, 0.1, 0.1]\nvoxels = [2, 2, 2]\n",
        &format!("mesh = \"organ.vtu\"\n{keys}\n"),
    )
}

#[test]
fn a_mesh_file_is_a_tensor_mass_source_in_its_unit() {
    use incise_sim::config::{LengthUnit, MeshSpec, TetSource};
    let source = |text: &str| match SceneConfig::from_toml(text, "t.toml").unwrap().model {
        Model::TensorMass(tm) => tm.source,
        Model::Hexahedra(_) => unreachable!("a mesh scene is tensor-mass"),
    };
    assert_eq!(
        source(&mesh_scene("")),
        TetSource::Mesh(MeshSpec {
            path: "organ.vtu".into(),
            unit: LengthUnit::Metre,
            region: None
        })
    );
    assert_eq!(
        source(&mesh_scene("unit = \"mm\"\nregion = \"medit:ref\"")),
        TetSource::Mesh(MeshSpec {
            path: "organ.vtu".into(),
            unit: LengthUnit::Millimetre,
            region: Some("medit:ref".into())
        })
    );
    let config = SceneConfig::from_toml(&mesh_scene("unit = \"cm\""), "t.toml").unwrap();
    assert_eq!((config.volume(), config.level()), (None, None));
    // A generated tensor-mass model keeps its volume and level.
    let generated = format!("level = 1\n{}", tensor_mass_scene("", "1e-4"));
    let config = SceneConfig::from_toml(&generated, "t.toml").unwrap();
    assert!(matches!(source(&generated), TetSource::Volume { level: 1, .. }));
    assert_eq!(config.level(), Some(1));

    // The mesh is on line 3, the keys from line 4.
    let cases = [
        // Hexahedra need a label volume.
        (
            mesh_scene("").replace("kind = \"tensor-mass\"\n", "kind = \"corotational\"\n"),
            3,
            "volume.mesh",
            "tensor-mass",
        ),
        (mesh_scene("unit = \"inch\""), 4, "volume.unit", "\"mm\""),
        (mesh_scene("region = \" \""), 4, "volume.region", "cell-data array"),
        (
            GOOD.replace("voxels = [2, 2, 2]", "voxels = [2, 2, 2]\nregion = \"tissue\""),
            6,
            "volume.region",
            "volume.mesh",
        ),
        (mesh_scene("stride = [2, 2, 2]"), 4, "volume.stride", "mesh file"),
        (mesh_scene("keep = [1]"), 4, "volume.keep", "mesh file"),
        (mesh_scene("voxels = [2, 2, 2]"), 4, "volume.voxels", "volume.mesh"),
        (mesh_scene("file = \"organ.nii\""), 3, "volume.mesh", "volume.file"),
        (format!("level = 1\n{}", mesh_scene("")), 1, "level", "mesh"),
        (
            GOOD.replace("voxels = [2, 2, 2]", "voxels = [2, 2, 2]\nunit = \"mm\""),
            6,
            "volume.unit",
            "volume.mesh",
        ),
        (
            mesh_scene("")
                .replace("procedural = \"block\"\n", "")
                .replace("mesh = \"organ.vtu\"\n", ""),
            2,
            "volume",
            "`mesh`",
        ),
    ];
    for (text, line, key, what) in cases {
        let e = error(&text);
        assert_eq!(where_(&e), (line, key.to_owned()), "{e}\n--- scene:\n{text}");
        assert!(e.to_string().contains(what), "{e}");
    }
}

#[test]
fn the_executor_is_a_scene_key() {
    use incise_sim::config::ExecSpec;
    let exec = |keys: &str| SceneConfig::from_toml(&format!("{GOOD}[exec]\n{keys}"), "t.toml");
    assert_eq!(SceneConfig::from_toml(GOOD, "t.toml").unwrap().exec, ExecSpec::default());
    assert_eq!(
        exec("threads = 1\nidle = \"sleep\"").unwrap().exec,
        ExecSpec { threads: Some(1), idle: Some(incise_fem::Idle::Sleep) }
    );
    assert_eq!(
        exec("idle = \"spin\"").unwrap().exec,
        ExecSpec { threads: None, idle: Some(incise_fem::Idle::DEFAULT_SPIN) }
    );
    let e = exec("threads = 0").unwrap_err();
    assert_eq!(where_(&e), (18, "exec.threads".to_owned()), "{e}");
    let e = exec("threads = 2\nidle = \"doze\"").unwrap_err();
    assert_eq!(where_(&e), (19, "exec.idle".to_owned()), "{e}");
    assert!(e.to_string().contains("\"spin\" or \"sleep\""), "{e}");
    assert!(matches!(exec("cores = 2").unwrap_err(), SceneError::Parse { line: 18, .. }));
    // What the scene says is what the executor gets, whatever the environment holds (the
    // programs apply `INCISE_THREADS` when they load a scene, not the library).
    let executor = exec("threads = 3\nidle = \"sleep\"").unwrap().exec.executor();
    assert_eq!((executor.threads(), executor.idle()), (3, incise_fem::Idle::Sleep));
}

/// The minimal block with `tools` appended (its first tool key is on line 18).
fn with_tools(tools: &str) -> String {
    format!("{GOOD}{tools}")
}

const SCALPEL: &str = "[[tools]]
name = \"scalpel\"
stiffness = 400.0
damping = 0.02
cutting = \"remove\"
outer = { shape = \"capsule\", radius = 0.002, length = 0.05 }
inner = { shape = \"blade\", length = 0.004, height = 0.003, thickness = 0.001, offset = [0.0, 0.0, 0.0005] }
[[tools.path]]
time = 0.0
position = [0.0, 0.0, 0.05]
[[tools.path]]
time = 1.0
position = [0.0, 0.0, 0.01]
rotation = [0.0, 1.0, 0.0, 0.0]
[[tools]]
name = \"grasper\"
stiffness = 300.0
outer = { mesh = \"tools/grasper.stl\", unit = \"mm\" }
[tools.jaws]
length = 0.01
width = 0.004
close_below = 0.05
open_above = 0.3
stiffness = 200.0
";

#[test]
fn tools_are_scene_keys() {
    use incise_sim::config::{Cutting, LengthUnit, ShapeSpec};
    use incise_tool::Primitive;
    let config = SceneConfig::from_toml(&with_tools(SCALPEL), "t.toml").unwrap();
    let [scalpel, grasper] = &config.tools[..] else { panic!("two tools") };
    assert_eq!(
        (scalpel.name.as_str(), scalpel.cutting, scalpel.stiffness),
        ("scalpel", Cutting::Remove, 400.0)
    );
    let Some(ShapeSpec::Shape(inner)) = &scalpel.inner else { panic!("an analytic inner shape") };
    assert!(matches!(inner.primitive(), Some(Primitive::Blade { .. })));
    let path = scalpel.path.as_ref().unwrap();
    let halfway = path.at(0.5);
    assert!((halfway.pose().position()[2] - 0.03).abs() < 1e-15);
    assert_eq!(grasper.cutting, Cutting::Off);
    assert_eq!(
        grasper.outer,
        ShapeSpec::Mesh {
            path: "tools/grasper.stl".into(),
            unit: LengthUnit::Millimetre,
            offset: [0.0; 3]
        }
    );
    assert!(grasper.jaws.is_some() && grasper.path.is_none());
}

#[test]
fn a_mesh_tool_may_push_by_volume_without_a_point_stiffness() {
    use incise_sim::config::ToolContact;
    let tools = SCALPEL.replace(
        "name = \"grasper\"\nstiffness = 300.0\n",
        "name = \"grasper\"\ncontact = \"volume\"\n",
    );
    let config = SceneConfig::from_toml(&with_tools(&tools), "t.toml").unwrap();
    let contact: Vec<(ToolContact, f64)> =
        config.tools.iter().map(|t| (t.contact, t.stiffness)).collect();
    assert_eq!(contact, [(ToolContact::Points, 400.0), (ToolContact::Volume, 0.0)]);
}

#[test]
fn tool_errors_name_the_key_and_line() {
    let first = GOOD.lines().count() + 1;
    let cases: Vec<(String, usize, &str, &str)> = vec![
        (SCALPEL.replace("stiffness = 400.0", "stiffness = -1.0"), first + 2, "tools[0].stiffness", "between"),
        (SCALPEL.replace("cutting = \"remove\"", "cutting = \"laser\""), first + 4, "tools[0].cutting", "laser"),
        (
            SCALPEL.replace("inner = { shape = \"blade\", length = 0.004, height = 0.003, thickness = 0.001, offset = [0.0, 0.0, 0.0005] }\n", ""),
            first + 4,
            "tools[0].cutting",
            "inner",
        ),
        (SCALPEL.replace("cutting = \"remove\"", "cutting = \"separate\"").replace("shape = \"blade\", length = 0.004, height = 0.003, thickness = 0.001", "shape = \"sphere\", radius = 0.001"), first + 4, "tools[0].cutting", "blade"),
        (SCALPEL.replace("radius = 0.002, length", "radius = 0.0, length"), first + 5, "tools[0].outer.radius", "positive"),
        (SCALPEL.replace("shape = \"capsule\", radius = 0.002, length = 0.05", "shape = \"capsule\", radius = 0.002"), first + 5, "tools[0].outer.length", "missing"),
        (SCALPEL.replace("shape = \"capsule\"", "shape = \"cone\""), first + 5, "tools[0].outer.shape", "cone"),
        (SCALPEL.replace("radius = 0.002, length = 0.05", "radius = 0.002, length = 0.05, thickness = 0.1"), first + 5, "tools[0].outer.thickness", "not a size"),
        (SCALPEL.replace("time = 1.0", "time = 0.0"), first + 11, "tools[0].path[1].time", "increasing"),
        (SCALPEL.replace("rotation = [0.0, 1.0, 0.0, 0.0]", "rotation = [0.0, 2.0, 0.0, 0.0]"), first + 13, "tools[0].path[1].rotation", "norm 2"),
        (SCALPEL.replace("name = \"grasper\"", "name = \"scalpel\""), first + 15, "tools[1].name", "two tools"),
        (SCALPEL.replace("unit = \"mm\"", "unit = \"inch\""), first + 17, "tools[1].outer.unit", "inch"),
        (SCALPEL.replace("open_above = 0.3", "open_above = 0.01"), first + 22, "tools[1].jaws.open_above", "close_below"),
        (SCALPEL.replace("stiffness = 400.0", "contact = \"volume\""), first + 2, "tools[0].contact", "mesh"),
        (SCALPEL.replace("stiffness = 400.0", "stiffness = 400.0\ncontact = \"springs\""), first + 3, "tools[0].contact", "springs"),
        (SCALPEL.replace("name = \"grasper\"\n", "name = \"grasper\"\ncontact = \"volume\"\n"), first + 17, "tools[1].stiffness", "pressure"),
        (SCALPEL.replace("damping = 0.02", "damping = 0.02\ncoupling_stiffness = -5.0"), first + 4, "tools[0].coupling_stiffness", "between"),
        (SCALPEL.replace("damping = 0.02", "damping = 0.02\ncoupling_damping = -1.0"), first + 4, "tools[0].coupling_damping", "-1"),
        (SCALPEL.replace("damping = 0.02", "damping = 0.02\nmax_force = 0.0"), first + 4, "tools[0].max_force", "positive"),
        (SCALPEL.replace("damping = 0.02", "damping = 0.02\nfriction = -0.1"), first + 4, "tools[0].friction", "-0.1"),
        (SCALPEL.replace("damping = 0.02", "damping = 0.02\ncut_force = 0.0"), first + 4, "tools[0].cut_force", "positive"),
        (SCALPEL.replace("name = \"grasper\"\n", "name = \"grasper\"\ncut_force = 1.0\n"), first + 16, "tools[1].cut_force", "cutting"),
        (SCALPEL.replace("name = \"grasper\"\nstiffness = 300.0\n", "name = \"grasper\"\ncontact = \"volume\"\ncoupling_stiffness = 500.0\n"), first + 17, "tools[1].coupling_stiffness", "volume"),
    ];
    for (tools, line, key, what) in cases {
        let text = with_tools(&tools);
        let e = error(&text);
        assert_eq!(where_(&e), (line, key.to_owned()), "{e}");
        assert!(e.to_string().contains(what), "{e}");
    }
}

#[test]
fn the_surface_keys_are_checked() {
    use incise_sim::config::SurfaceSpec;
    let config = SceneConfig::from_toml(
        &format!("{GOOD}[surface]\ninterfaces = true\nsmoothing = 3\n"),
        "t.toml",
    )
    .unwrap();
    assert_eq!(config.surface, SurfaceSpec { interfaces: true, smoothing: 3 });
    assert_eq!(SceneConfig::from_toml(GOOD, "t.toml").unwrap().surface, SurfaceSpec::default());
    let e = error(&format!("{GOOD}[surface]\nsmoothing = 1000\n"));
    let line = GOOD.lines().count() + 2;
    assert_eq!(where_(&e), (line, "surface.smoothing".to_owned()), "{e}");
    let e = error(&format!("{GOOD}[surface]\nsmooth = 2\n"));
    assert!(e.to_string().contains("smooth"), "{e}");
}

#[test]
fn the_volume_contact_keys_are_checked() {
    use incise_sim::config::VolumeContactSpec;
    let two = GOOD.replace(
        "[integrator]",
        "[[materials]]\nlabel = 2\nyoungs_modulus = 3000.0\npoisson_ratio = 0.3\ndensity = 1000.0\n[integrator]",
    );
    let config = SceneConfig::from_toml(
        &format!(
            "{two}[surface]\ninterfaces = true\n[volume_contact]\npressure = 2e6\nresolution = 48\n\
             pairs = [[2, 1]]\nself = true\n"
        ),
        "t.toml",
    )
    .unwrap();
    let want = VolumeContactSpec {
        pressure: 2e6,
        resolution: 48,
        pairs: vec![[1, 2]],
        self_contact: true,
    };
    assert_eq!(config.volume_contact, Some(want));
    let config =
        SceneConfig::from_toml(&format!("{GOOD}[volume_contact]\nself = true\n"), "t.toml")
            .unwrap();
    let spec = config.volume_contact.unwrap();
    assert_eq!(
        (spec.pressure, spec.resolution),
        (VolumeContactSpec::DEFAULT_PRESSURE, VolumeContactSpec::DEFAULT_RESOLUTION)
    );
    assert_eq!(SceneConfig::from_toml(GOOD, "t.toml").unwrap().volume_contact, None);

    // Each error names its key on the line after `[volume_contact]`.
    let cases = [
        (GOOD, "pressure = -1.0\nself = true", "volume_contact.pressure", "between"),
        (GOOD, "resolution = 0\nself = true", "volume_contact.resolution", "between 1 and 1024"),
        (GOOD, "pairs = [[1, 7]]", "volume_contact.pairs[0]", "label 7"),
        (GOOD, "pairs = [[1, 1]]", "volume_contact.pairs[0]", "self = true"),
        (&two, "pairs = [[1, 2]]", "volume_contact.pairs", "interfaces = true"),
    ];
    for (base, keys, key, says) in cases {
        let e = error(&format!("{base}[volume_contact]\n{keys}\n"));
        assert_eq!(where_(&e), (base.lines().count() + 2, key.to_owned()), "{e}");
        assert!(e.to_string().contains(says), "{e}");
    }
    let e = error(&format!("{GOOD}[volume_contact]\npressure = 1e6\n"));
    assert!(e.to_string().contains("nothing to do"), "{e}");
    let e = error(&format!(
        "{two}[surface]\ninterfaces = true\n[volume_contact]\npairs = [[1, 2], [2, 1]]\n"
    ));
    assert!(e.to_string().contains("repeats"), "{e}");
    let e = error(&format!("{GOOD}[volume_contact]\nself = true\nmargin = 3\n"));
    assert!(e.to_string().contains("margin"), "{e}");
}
