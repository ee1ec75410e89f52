//! Writing a file the user named (`-o`), never destroying what was there.
//!
//! - `-` is standard output.
//! - A regular file is replaced atomically: the bytes go to a temporary file
//!   beside it, which is renamed over it once complete, so a failure leaves the
//!   old file whole. It keeps its permissions.
//! - A symbolic link is written through: its target is replaced, the link
//!   stays.
//! - Anything else that exists (a device such as `/dev/null`, a FIFO, a
//!   terminal, `/dev/stdout`) is opened and written to, never replaced.
//! - A directory is refused.
//!
//! ```
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("model.json");
//! vocabulary::output::write_file(&path, b"{}\n").unwrap();
//! assert_eq!(std::fs::read(&path).unwrap(), b"{}\n");
//! ```

use std::fs::{self, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use crate::Failure;

/// Writes `bytes` to `path` as the module says.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), Failure> {
    let fail = |e: io::Error| Failure::Io(format!("cannot write {}: {e}", path.display()));
    if path.as_os_str() == "-" {
        let mut out = io::stdout().lock();
        return out
            .write_all(bytes)
            .and_then(|()| out.flush())
            .map_err(fail);
    }
    match fs::metadata(path) {
        Ok(meta) if meta.is_dir() => Err(Failure::BadInput(format!(
            "{}: is a directory, not a file to write to",
            path.display()
        ))),
        Ok(meta) if !meta.is_file() => {
            // A device, a FIFO, a terminal: written to, never replaced.
            let mut file = OpenOptions::new().write(true).open(path).map_err(fail)?;
            file.write_all(bytes)
                .and_then(|()| file.flush())
                .map_err(fail)
        }
        _ => {
            let target = target(path).map_err(fail)?;
            replace(&target, bytes).map_err(|e| match e.kind() {
                io::ErrorKind::NotFound => Failure::BadInput(format!(
                    "{}: no such directory to write {} in",
                    directory(&target).display(),
                    target.file_name().unwrap_or_default().to_string_lossy()
                )),
                _ => fail(e),
            })
        }
    }
}

/// The directory a file is in (`.` for a bare name).
fn directory(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// The file a path names once symbolic links are followed (the last link's
/// target when it does not exist yet).
fn target(path: &Path) -> io::Result<PathBuf> {
    let mut path = path.to_path_buf();
    // As the kernel does, give up on a loop of links.
    for _ in 0..40 {
        match fs::symlink_metadata(&path) {
            Ok(meta) if meta.file_type().is_symlink() => {
                let link = fs::read_link(&path)?;
                path = match path.parent() {
                    Some(dir) => dir.join(link),
                    None => link,
                };
            }
            _ => return Ok(path),
        }
    }
    Err(io::Error::other("too many levels of symbolic links"))
}

/// Replaces the regular file `path` (or creates it) through a temporary file
/// in its directory.
fn replace(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut tmp = tempfile::Builder::new()
        .prefix(".gardefou-")
        .tempfile_in(directory(path))?;
    tmp.write_all(bytes)?;
    tmp.as_file().sync_all()?;
    // A temporary file is private; what replaces a file keeps its permissions.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = fs::metadata(path).map_or(0o644, |m| m.permissions().mode() & 0o7777);
        tmp.as_file()
            .set_permissions(fs::Permissions::from_mode(mode))?;
    }
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_regular_file_is_replaced_and_keeps_its_permissions() {
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("out.json");
        fs::write(&path, "old").expect("old");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            fs::set_permissions(&path, fs::Permissions::from_mode(0o640)).expect("mode");
        }
        write_file(&path, b"new").expect("writes");
        assert_eq!(fs::read(&path).expect("read"), b"new");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = fs::metadata(&path).expect("meta").permissions().mode();
            assert_eq!(mode & 0o777, 0o640);
        }
        let left: Vec<_> = fs::read_dir(dir.path()).expect("dir").collect();
        assert_eq!(left.len(), 1, "a temporary file left: {left:?}");
    }

    #[cfg(unix)]
    #[test]
    fn a_symbolic_link_is_written_through() {
        let dir = tempfile::tempdir().expect("dir");
        let real = dir.path().join("real.json");
        let link = dir.path().join("link.json");
        fs::write(&real, "old").expect("old");
        std::os::unix::fs::symlink("real.json", &link).expect("link");
        write_file(&link, b"new").expect("writes");
        assert!(
            fs::symlink_metadata(&link)
                .expect("meta")
                .file_type()
                .is_symlink()
        );
        assert_eq!(fs::read(&real).expect("read"), b"new");
        // A link to a file not there yet creates the file.
        let dangling = dir.path().join("later.json");
        std::os::unix::fs::symlink("sub/../made.json", &dangling).expect("link");
        fs::create_dir(dir.path().join("sub")).expect("sub");
        write_file(&dangling, b"made").expect("writes");
        assert!(
            fs::symlink_metadata(&dangling)
                .expect("meta")
                .file_type()
                .is_symlink()
        );
        assert_eq!(
            fs::read(dir.path().join("made.json")).expect("read"),
            b"made"
        );
    }

    #[cfg(unix)]
    #[test]
    fn a_fifo_is_written_to_not_replaced() {
        let dir = tempfile::tempdir().expect("dir");
        let fifo = dir.path().join("fifo");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.expect("mkfifo runs").success());
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || fs::read(fifo).expect("reads the FIFO"))
        };
        write_file(&fifo, b"through").expect("writes");
        assert_eq!(reader.join().expect("reader"), b"through");
        assert!(!fs::symlink_metadata(&fifo).expect("meta").is_file());
    }

    #[test]
    fn a_directory_is_refused() {
        let dir = tempfile::tempdir().expect("dir");
        let err = write_file(dir.path(), b"x").expect_err("refused");
        assert!(matches!(err, Failure::BadInput(m) if m.contains("is a directory")));
        let err = write_file(&dir.path().join("no/such.json"), b"x").expect_err("refused");
        assert!(
            matches!(&err, Failure::BadInput(m) if m.ends_with("no: no such directory to write such.json in")),
            "{err:?}"
        );
    }
}
