//! What the `policy` fuzz target checks, as a plain function: `stages/reconstruction/tests/corpus.rs`
//! replays the committed corpus through it without libFuzzer.

use neuspike_reconstruction::policy::Policy;
use neuspike_representations::WindowStats;

/// A policy file as `--method auto --policy FILE` reads it (`Policy::from_yaml`): any text gives
/// a policy or an error, never a panic. A policy that reads chooses a method that it names for
/// windows from dark and still to bright and fast, with and without events; restricted to some
/// of its methods it still chooses among them or says which class cannot run; written out, it
/// reads back the same.
pub fn policy(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(p) = Policy::from_yaml(text, "fuzz.yml") else {
        return;
    };
    let named = p
        .all_methods()
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>();
    let windows = [
        (0.0, 0.0, 0.0, 0.0, false, 0.0),
        (0.01, 0.0, 0.1, 1.0, false, 0.05),
        (0.3, 0.02, 0.5, 3.0, true, 0.4),
        (1.0, 1.0, 1.0, 12.0, true, 5.0),
        (f64::MAX, f64::MAX, 1.0, f64::MAX, true, f64::MAX),
    ];
    let runnable = |m: &str| m.len().is_multiple_of(2);
    let restricted = p.restricted(runnable, true);
    for (rate, event_rate, change, spread_decades, events, edge) in windows {
        let s = WindowStats {
            rate,
            event_rate,
            change,
            spread_decades,
            events,
            edge,
        };
        let m = p.choose(&s).to_string();
        assert!(
            named.contains(&m),
            "chose {m:?}, which the policy does not name"
        );
        let pooled = p.pooled_class(&s, 5);
        assert!(named.contains(&pooled.method), "pooled {:?}", pooled.method);
        if let Ok(r) = &restricted {
            assert!(
                runnable(r.choose(&s)),
                "restricted chose {:?}",
                r.choose(&s)
            );
        }
    }
    let again = Policy::from_yaml(&p.to_yaml(), "again.yml").expect("a policy written reads back");
    assert_eq!(again.all_methods(), p.all_methods());
}
