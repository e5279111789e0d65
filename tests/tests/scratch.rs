//! The scratch directories of `hinge_tests::Scratch`.

use hinge_tests::Scratch;
use std::path::PathBuf;

#[test]
fn a_scratch_directory_is_removed_also_when_its_test_panics() {
    let kept = std::panic::catch_unwind(|| {
        let dir = Scratch::new("tests-scratch-panics");
        std::fs::write(dir.join("f.txt"), "x").unwrap();
        assert!(dir.join("f.txt").is_file());
        panic_with(dir.to_path_buf())
    });
    let path = *kept.unwrap_err().downcast::<PathBuf>().unwrap();
    assert!(!path.exists(), "{} left behind", path.display());
}

fn panic_with(path: PathBuf) -> ! {
    std::panic::panic_any(path)
}
