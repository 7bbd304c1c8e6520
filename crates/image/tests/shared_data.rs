//! Loads every scene of the shared Middlebury data (`STEREOLINK_DATA`) and
//! checks sizes, ground-truth scales and masks against `manifest.json`.

use stereolink_image::{colormap::finite_range, Scene};

#[test]
fn every_shared_scene_loads_with_manifest_sizes_scales_and_masks() {
    let Some(dir) = stereolink_image::shared_data::dir() else {
        return;
    };
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
    let scenes = manifest["scenes"].as_object().unwrap();
    assert_eq!(scenes.len(), 20);
    for (name, entry) in scenes {
        let scene = Scene::load(dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let (w, h) = (
            entry["width"].as_u64().unwrap() as usize,
            entry["height"].as_u64().unwrap() as usize,
        );
        assert_eq!(scene.left.dims(), (w, h), "{name}");
        assert_eq!(scene.right.dims(), (w, h), "{name}");
        assert_eq!(
            scene.calib.ndisp as u64,
            entry["ndisp"].as_u64().unwrap(),
            "{name}"
        );
        // The ground truth range in pixels matches the manifest: the scale was applied.
        let gt = scene
            .gt_left
            .as_ref()
            .unwrap_or_else(|| panic!("{name}: no ground truth"));
        let (lo, hi) = finite_range(gt).unwrap();
        let range = entry["gt_left_range_px"].as_array().unwrap();
        assert!(
            (lo as f64 - range[0].as_f64().unwrap()).abs() < 0.02,
            "{name}: min {lo}"
        );
        assert!(
            (hi as f64 - range[1].as_f64().unwrap()).abs() < 0.02,
            "{name}: max {hi}"
        );
        let known = gt.as_slice().iter().filter(|d| d.is_finite()).count() as f64 / gt.len() as f64;
        assert!(
            (known - entry["gt_valid_fraction"].as_f64().unwrap()).abs() < 0.002,
            "{name}: known {known}"
        );
        // Every scene has a non-occluded mask: shipped, or derived from both ground truths.
        let nonocc = scene
            .masks
            .nonocc
            .as_ref()
            .unwrap_or_else(|| panic!("{name}: no nonocc mask"));
        let share = nonocc.as_slice().iter().filter(|&&b| b).count() as f64 / nonocc.len() as f64;
        assert!((0.5..1.0).contains(&share), "{name}: nonocc share {share}");
        let files = entry["files"].as_object().unwrap();
        assert_eq!(
            scene.masks.all.is_some(),
            files.contains_key("mask_all.png"),
            "{name}"
        );
        assert_eq!(
            scene.gt_right.is_some(),
            files.contains_key("gt_right.png"),
            "{name}"
        );
        if entry["year"].as_u64() == Some(2014) {
            assert!(
                scene.calib.focal_px.unwrap() > 100.0 && scene.calib.baseline_m.unwrap() > 0.05,
                "{name}"
            );
        }
    }
}
