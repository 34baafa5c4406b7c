//! The real fixture, `tests/data/liver.inr.gz`: a segmented liver CT volume.

#![allow(clippy::float_cmp, reason = "exact values are written and must read back exactly")]

use incise_io::{read_inr, read_volume};
use std::path::Path;

const LIVER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/liver.inr.gz");

#[test]
fn liver_fixture_has_the_documented_extent_spacing_and_labels() {
    let v = read_volume(Path::new(LIVER)).unwrap();
    assert_eq!(v.dims(), [438, 353, 165]);
    let want = [0.617_188e-3, 0.617_188e-3, 1.333_33e-3];
    for (got, want) in v.spacing().iter().zip(want) {
        assert!((got - want).abs() <= 1e-12 * want, "spacing {:?}", v.spacing());
    }
    assert_eq!(v.origin(), [0.0; 3]);

    let total = 438 * 353 * 165;
    let foreground = [(84, 2), (85, 17_702), (127, 314_086), (255, 3_160_496)];
    let background = total - foreground.iter().map(|&(_, n)| n).sum::<usize>();
    let mut want = vec![(0u16, background)];
    want.extend(foreground);
    assert_eq!(v.histogram(), want);
}

#[test]
fn liver_fixture_reads_the_same_through_read_inr() {
    let a = read_inr(Path::new(LIVER)).unwrap();
    assert_eq!(a.dims(), [438, 353, 165]);
    assert_eq!(a.foreground_count(), 2 + 17_702 + 314_086 + 3_160_496);
}
