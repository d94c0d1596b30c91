//! The shared conformance suite, one line per configuration.

#![allow(clippy::panic)]

const CONFIGS: [&str; 2] = ["l4dr-like", "lirafusion-like"];

#[test]
fn conformance() {
    let mut r = hilo_fusion::Registry::with_builtin();
    hilo_fusion_early::register(&mut r)
        .map_err(|e| e.to_string())
        .and_then(|_| {
            CONFIGS.iter().try_for_each(|name| {
                hilo_fusion::preset(name)
                    .map_err(|e| e.to_string())
                    .and_then(|c| hilo_fusion::conformance::check(&r, &c))
            })
        })
        .unwrap_or_else(|e| panic!("{e}"));
}
