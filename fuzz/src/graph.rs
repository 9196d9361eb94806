//! What the `graph` fuzz target checks, as a plain function: `pipeline/tests/corpus.rs` replays
//! the committed corpus through it without libFuzzer.

/// A graph file as `neuspike run`, `neuspike graph` and `--in-process` read it: any text gives a
/// graph or an error, never a panic. A graph that derives draws, and derives again to
/// itself (a graph written out whole is its own derivation); the in-process reading of the same
/// text (`GraphChain::from_yaml`) gives a chain or an error.
pub fn graph(data: &[u8]) {
    use neuspike_pipeline::{GraphChain, derive};
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = GraphChain::from_yaml(text);
    let Ok(mut g) = serde_yaml::from_str::<serde_yaml::Value>(text) else {
        return;
    };
    let _ = derive::edges(&g);
    if derive::derive(&mut g, 4, Some("cargo build")).is_ok() {
        let drawn = derive::draw(&g).expect("a derived graph draws");
        let mut again = g.clone();
        derive::derive(&mut again, 4, Some("cargo build")).expect("a derived graph derives");
        assert_eq!(again, g, "a derived graph derives to another:\n{drawn}");
    }
}
