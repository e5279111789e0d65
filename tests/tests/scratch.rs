//! Scratch directories for tests that write files: removed when the guard is dropped, so a test that
//! fails (panics) leaves nothing behind in the temporary directory either.

use std::path::{Path, PathBuf};

/// A directory under the system's temporary directory, unique to the test process and `name`; removed
/// with everything in it when dropped.
pub struct Scratch(PathBuf);

impl Scratch {
    /// Creates (or empties and reuses) `hinge-tests-{name}-{pid}` in the temporary directory.
    pub fn new(name: &str) -> Scratch {
        let d = std::env::temp_dir().join(format!("hinge-tests-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Scratch(d)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

#[test]
fn a_scratch_directory_is_removed_also_when_its_test_panics() {
    let kept = std::panic::catch_unwind(|| {
        let dir = Scratch::new("scratch-panics");
        std::fs::write(dir.join("f.txt"), "x").unwrap();
        assert!(dir.join("f.txt").is_file());
        let path = dir.to_path_buf();
        panic_with(path)
    });
    let path = *kept.unwrap_err().downcast::<PathBuf>().unwrap();
    assert!(!path.exists(), "{} left behind", path.display());
}

fn panic_with(path: PathBuf) -> ! {
    std::panic::panic_any(path)
}
