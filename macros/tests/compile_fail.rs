//! What the derive macro must reject, with the messages pinned (`macros/tests/ui/*.stderr`; regenerate with
//! `TRYBUILD=overwrite cargo test -p hinge-macros --release --test compile_fail` after a deliberate change).

#[test]
fn derive_rejects_unsupported_input() {
    let t = trybuild::TestCases::new();
    t.compile_fail("tests/ui/*.rs");
}
