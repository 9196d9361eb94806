//! What the `scene` fuzz target checks, as a plain function: `scene/tests/corpus.rs` replays the
//! committed corpus through it without libFuzzer.

/// Scene YAML (`Scene::from_yaml_str`): any text gives a scene or an error, never a panic; a
/// scene that builds renders a small view at three instants, every pixel finite and
/// non-negative.
pub fn scene(data: &[u8]) {
    use neuspike_scene::Scene;
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(scene) = Scene::from_yaml_str(text, "fuzz.yml", None) else {
        return;
    };
    for t_ns in [0, 1_000_000, 50_000_000] {
        let view = scene.render(t_ns, 8, 12);
        assert!(
            view.iter().all(|v| v.is_finite() && *v >= 0.0),
            "a rendered pixel is negative or not finite"
        );
    }
}
