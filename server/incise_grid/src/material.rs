//! Tissue materials and the label → material table.
//!
//! Each label of a segmentation maps to one isotropic linear-elastic [`Material`]; with several
//! labels the grid condenses each voxel with its own material (heterogeneous condensation, the
//! extension of Jeřábková 2010 §2.2 that the paper leaves as future work).

use crate::error::VolumeError;
use std::collections::BTreeMap;

/// An isotropic tissue: Young's modulus, Poisson ratio, density and Rayleigh damping.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Young's modulus E in Pa.
    pub youngs_modulus: f64,
    /// Poisson ratio ν, in (−1, 0.5).
    pub poisson_ratio: f64,
    /// Density ρ in kg/m³.
    pub density: f64,
    /// Rayleigh mass-proportional damping α in 1/s (damping matrix αM + βK).
    pub rayleigh_mass: f64,
    /// Rayleigh stiffness-proportional damping β in s.
    pub rayleigh_stiffness: f64,
}

impl Material {
    /// A material with no damping.
    #[must_use]
    pub fn new(youngs_modulus: f64, poisson_ratio: f64, density: f64) -> Self {
        Self { youngs_modulus, poisson_ratio, density, rayleigh_mass: 0.0, rayleigh_stiffness: 0.0 }
    }

    /// Soft parenchyma in the range reported for human liver in vivo (E ≈ 3–6 kPa).
    #[must_use]
    pub fn liver() -> Self {
        Self {
            youngs_modulus: 4_500.0,
            poisson_ratio: 0.45,
            density: 1_060.0,
            rayleigh_mass: 0.1,
            rayleigh_stiffness: 0.01,
        }
    }

    /// Checks every parameter is physical; `label` only names the material in the error.
    pub fn validate(&self, label: u16) -> Result<(), VolumeError> {
        let bad = |what: String| Err(VolumeError::BadMaterial { label, what });
        if !(self.youngs_modulus.is_finite() && self.youngs_modulus > 0.0) {
            return bad(format!(
                "Young's modulus {} Pa must be finite and positive",
                self.youngs_modulus
            ));
        }
        if !(self.poisson_ratio > -1.0 && self.poisson_ratio < 0.5) {
            return bad(format!("Poisson ratio {} must lie in (-1, 0.5)", self.poisson_ratio));
        }
        if !(self.density.is_finite() && self.density > 0.0) {
            return bad(format!("density {} kg/m^3 must be finite and positive", self.density));
        }
        if !(self.rayleigh_mass.is_finite() && self.rayleigh_mass >= 0.0) {
            return bad(format!(
                "Rayleigh mass damping {} must be finite and non-negative",
                self.rayleigh_mass
            ));
        }
        if !(self.rayleigh_stiffness.is_finite() && self.rayleigh_stiffness >= 0.0) {
            return bad(format!(
                "Rayleigh stiffness damping {} must be finite and non-negative",
                self.rayleigh_stiffness
            ));
        }
        Ok(())
    }
}

/// Maps labels to materials. Material indices (used by the grid) follow label order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaterialTable {
    by_label: BTreeMap<u16, Material>,
}

impl MaterialTable {
    /// An empty table.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Every non-zero label gets `material` (handy for procedural volumes and tests).
    #[must_use]
    pub fn uniform(labels: &[u16], material: Material) -> Self {
        let mut t = Self::new();
        for &l in labels {
            t.insert(l, material);
        }
        t
    }

    /// The abdominal CT fixture's labels: 255 liver, 127 kidney (stiffer), 85 gallbladder (softer,
    /// fluid-filled). Values are typical of the elastography literature, not patient-specific.
    #[must_use]
    pub fn abdominal_ct() -> Self {
        let mut t = Self::new();
        t.insert(255, Material::liver());
        t.insert(127, Material { youngs_modulus: 10_000.0, ..Material::liver() });
        t.insert(
            85,
            Material {
                youngs_modulus: 2_000.0,
                poisson_ratio: 0.48,
                density: 1_020.0,
                ..Material::liver()
            },
        );
        t
    }

    /// Sets the material of `label` (label 0 is always empty and is ignored).
    pub fn insert(&mut self, label: u16, material: Material) {
        if label != 0 {
            self.by_label.insert(label, material);
        }
    }

    /// The material of `label`, if any.
    #[must_use]
    pub fn get(&self, label: u16) -> Option<&Material> {
        self.by_label.get(&label)
    }

    /// `(label, material)` pairs in label order; the position is the material index.
    pub fn iter(&self) -> impl Iterator<Item = (u16, &Material)> {
        self.by_label.iter().map(|(&l, m)| (l, m))
    }

    /// Number of materials.
    #[must_use]
    pub fn len(&self) -> usize {
        self.by_label.len()
    }

    /// True when no label has a material.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.by_label.is_empty()
    }
}

/// Which labels to keep, and which to merge into others, before building a grid
/// (e.g. liver only: `keep [255]`; the fixture's 2 stray voxels: `merge 84 → 85`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LabelFilter {
    keep: Option<Vec<u16>>,
    merge: BTreeMap<u16, u16>,
}

impl LabelFilter {
    /// Keeps every label, merges nothing.
    #[must_use]
    pub fn all() -> Self {
        Self::default()
    }

    /// Keeps only `labels` (after merging); every other label becomes 0.
    #[must_use]
    pub fn keep(mut self, labels: &[u16]) -> Self {
        let mut k = labels.to_vec();
        k.sort_unstable();
        k.dedup();
        self.keep = Some(k);
        self
    }

    /// Relabels `from` as `into` (applied before `keep`).
    #[must_use]
    pub fn merge(mut self, from: u16, into: u16) -> Self {
        self.merge.insert(from, into);
        self
    }

    /// The fixture's clean-up: the two stray voxels of label 84 join the gallbladder (85).
    #[must_use]
    pub fn abdominal_ct() -> Self {
        Self::all().merge(84, 85)
    }

    /// The label `l` becomes.
    #[must_use]
    pub fn apply(&self, l: u16) -> u16 {
        let l = self.merge.get(&l).copied().unwrap_or(l);
        match &self.keep {
            Some(k) if k.binary_search(&l).is_err() => 0,
            _ => l,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filter_merges_then_keeps() {
        let f = LabelFilter::all().merge(84, 85).keep(&[85]);
        assert_eq!(f.apply(84), 85);
        assert_eq!(f.apply(85), 85);
        assert_eq!(f.apply(255), 0);
        assert_eq!(LabelFilter::all().apply(9), 9);
    }

    #[test]
    fn bad_materials_name_the_label() {
        let err = Material::new(1e3, 0.5, 1000.0).validate(12).unwrap_err();
        assert!(
            err.to_string().contains("label 12") && err.to_string().contains("Poisson"),
            "{err}"
        );
        assert!(Material::new(-1.0, 0.3, 1.0).validate(1).is_err());
        assert!(Material::new(1.0, 0.3, f64::NAN).validate(1).is_err());
        assert!(Material::liver().validate(1).is_ok());
    }
}
