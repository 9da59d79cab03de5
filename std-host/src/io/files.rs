//! Files in and out, safely: every input must be a regular file (a FIFO would block the
//! command forever, a directory only fails later with a bare OS error), every error names the
//! file, and every output is written to a `.partial` file first and renamed into place, so a
//! failure never leaves a half-written output behind.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

/// Checks that `path` (the `what` of the command, e.g. "weight blob") is an existing regular
/// file, following symbolic links; returns it for chaining.
pub fn input<'p>(path: &'p Path, what: &str) -> Result<&'p Path> {
    let meta = match std::fs::metadata(path) {
        Ok(meta) => meta,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("{what} {} does not exist", path.display())
        }
        Err(e) => return Err(e).with_context(|| format!("cannot read {what} {}", path.display())),
    };
    if !meta.is_file() {
        bail!("{what} {} is {}, not a file", path.display(), kind(&meta.file_type()));
    }
    Ok(path)
}

fn kind(file_type: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if file_type.is_fifo() {
            return "a named pipe (FIFO)";
        }
        if file_type.is_socket() {
            return "a socket";
        }
        if file_type.is_block_device() || file_type.is_char_device() {
            return "a device";
        }
    }
    if file_type.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

/// The bytes of the input file `path` ([`input`] first); an empty file is an error.
pub fn read(path: &Path, what: &str) -> Result<Vec<u8>> {
    let bytes = std::fs::read(input(path, what)?).with_context(|| format!("cannot read {what} {}", path.display()))?;
    if bytes.is_empty() {
        bail!("{what} {} is empty (0 bytes)", path.display());
    }
    Ok(bytes)
}

/// The input file `path` as UTF-8 text; a byte sequence that is not UTF-8 is an error naming
/// its line.
pub fn read_text(path: &Path, what: &str) -> Result<String> {
    let bytes = read(path, what)?;
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let line = 1 + e.as_bytes()[..at].iter().filter(|&&b| b == b'\n').count();
        anyhow::anyhow!("{what} {}: line {line} is not UTF-8 text", path.display())
    })
}

/// Creates the output folder `dir` (and its parents), with an error naming it.
pub fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create output folder {}", dir.display()))
}

/// Checks, before any work, that `dir` can be an output folder: it is a folder already, or the
/// nearest part of its path that exists is one (nothing is created here). The error names the
/// part that is a file.
pub fn check_output_dir(dir: &Path, flag: &str) -> Result<()> {
    for part in dir.ancestors().filter(|p| !p.as_os_str().is_empty()) {
        match std::fs::metadata(part) {
            Ok(meta) if meta.is_dir() => return Ok(()),
            Ok(_) if part == dir => bail!("{flag} {}: is a file, not a folder", dir.display()),
            Ok(_) => bail!(
                "{flag} {}: cannot create the folder, {} is a file",
                dir.display(),
                part.display()
            ),
            // Missing, or below a file: the nearest existing part says which.
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::NotFound | std::io::ErrorKind::NotADirectory
                ) =>
            {
                continue
            }
            Err(e) => bail!("{flag} {}: {e}", dir.display()),
        }
    }
    // A relative path whose every part is missing lies in the current folder.
    Ok(())
}

/// The temporary name `path` is written under before it is renamed into place.
pub fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    path.with_file_name(name)
}

/// Writes `path` through `write` into its `.partial` twin, then renames it into place; the
/// parent folder is created if missing. On failure the partial file is removed.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> Result<()>,
) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        create_dir(dir)?;
    }
    let tmp = partial_path(path);
    let result = (|| {
        let file = std::fs::File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
        let mut writer = std::io::BufWriter::new(file);
        write(&mut writer).with_context(|| format!("cannot write {}", tmp.display()))?;
        writer
            .into_inner()
            .map_err(|e| e.into_error())
            .with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::rename(&tmp, path).with_context(|| format!("cannot move output into {}", path.display()))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// [`write_atomic`] of a byte buffer.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |w| Ok(w.write_all(bytes)?))
}

/// The SHA-256 of `bytes` as 64 lowercase hex digits: how reports and the manifest name the
/// exact blob or ELF they were made with.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// [`write_atomic`] of a picture as PNG.
pub fn save_png(image: &image::DynamicImage, path: &Path) -> Result<()> {
    write_atomic(path, |w| Ok(image.write_to(w, image::ImageFormat::Png)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("bino-files-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn sha256_matches_the_fips_180_examples() {
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(
            sha256_hex(b""),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
    }

    #[test]
    fn inputs_must_be_regular_nonempty_files() {
        let dir = scratch("inputs");
        let err = format!("{:#}", read(&dir, "weight blob").unwrap_err());
        assert!(err.contains("is a directory, not a file"), "{err}");
        let empty = dir.join("empty.bin");
        std::fs::write(&empty, b"").unwrap();
        let err = format!("{:#}", read(&empty, "weight blob").unwrap_err());
        assert!(err.contains("empty.bin is empty (0 bytes)"), "{err}");
        let missing = dir.join("missing.bin");
        let err = format!("{:#}", read(&missing, "weight blob").unwrap_err());
        assert!(err.contains("missing.bin does not exist"), "{err}");
        let text = dir.join("index.tsv");
        std::fs::write(&text, b"a\tb\nc\xff\td\n").unwrap();
        let err = format!("{:#}", read_text(&text, "pair index").unwrap_err());
        assert!(err.contains("index.tsv: line 2 is not UTF-8"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn failed_writes_leave_nothing_behind() {
        let dir = scratch("writes");
        let out = dir.join("report.json");
        let err = write_atomic(&out, |w| {
            w.write_all(b"half")?;
            bail!("interrupted")
        });
        assert!(err.is_err());
        assert_eq!(
            std::fs::read_dir(&dir).unwrap().count(),
            0,
            "no output, no partial file"
        );
        write_bytes(&out, b"{}").unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), b"{}");
        // A parent that is a file cannot hold an output folder.
        let err = format!("{:#}", write_bytes(&out.join("x.json"), b"{}").unwrap_err());
        assert!(err.contains("cannot create output folder"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_output_folder_that_is_a_file_is_refused_before_any_work() {
        let dir = scratch("out-check");
        let file = dir.join("taken");
        std::fs::write(&file, b"x").unwrap();
        check_output_dir(&dir, "--out").unwrap();
        check_output_dir(&dir.join("new/deeper"), "--out").unwrap();
        check_output_dir(Path::new("relative-and-missing"), "--out").unwrap();
        let err = check_output_dir(&file, "--out").unwrap_err().to_string();
        assert!(
            err.contains("is a file, not a folder") && err.contains("taken"),
            "{err}"
        );
        let err = check_output_dir(&file.join("below"), "--out").unwrap_err().to_string();
        assert!(
            err.contains("cannot create the folder") && err.contains("taken"),
            "{err}"
        );
        assert!(!dir.join("new").exists(), "nothing created");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
