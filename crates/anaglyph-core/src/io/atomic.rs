//! Crash-safe output: write into a temporary file beside the target, flush, then
//! rename over it, so readers see the old file or the whole new one, never a part, even
//! when anaglyph is killed mid-write. What a killed write left (`.NAME.tmp-PID` of a
//! process that no longer runs) is removed by the next write of the same file. (There is no fsync: durability across a power loss
//! is left to the operating system, as numpy and most tools do; an fsync of a 400 MB
//! cube cost about a second here.)

use crate::{Error, Result};
use std::io::{BufWriter, Write};
use std::path::Path;

/// Writes `path` through `fill`, atomically.
pub fn write_atomically(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let file_name = path.file_name().ok_or_else(|| {
        Error::output_conflict(
            "output path",
            format!("'{}' without a file name", path.display()),
            "a path to a file",
        )
    })?;
    let prefix = format!(".{}.tmp-", file_name.to_string_lossy());
    super::output_folder::remove_leftovers_of_dead_runs(dir, &prefix);
    let tmp = dir.join(format!("{prefix}{}", std::process::id()));
    let result = (|| -> std::io::Result<()> {
        let file = std::fs::File::create(&tmp)?;
        let mut writer = BufWriter::new(file);
        fill(&mut writer)?;
        writer.into_inner().map_err(|e| e.into_error())?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failing_writer_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        let err = write_atomically(&path, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("disk full"))
        });
        assert_eq!(err.err().map(|e| e.kind()), Some("Io"));
        assert!(!path.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        write_atomically(&path, |w| w.write_all(b"whole")).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"whole");
    }

    #[test]
    fn what_a_killed_write_left_is_removed_by_the_next() {
        let dir = tempfile::tempdir().unwrap();
        let killed = dir.path().join(".out.bin.tmp-4294967295");
        let other = dir.path().join(".other.bin.tmp-4294967295");
        std::fs::write(&killed, b"half").unwrap();
        std::fs::write(&other, b"half").unwrap();
        write_atomically(&dir.path().join("out.bin"), |w| w.write_all(b"whole")).unwrap();
        assert!(!killed.exists() && other.exists());
    }
}
