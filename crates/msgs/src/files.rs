//! Output files of a run: never one of its inputs.
//!
//! Outputs are written under a temporary name and renamed into place when finished
//! ([`crate::recording::Recorder`], [`crate::npy::write`]), so a failed run never destroys
//! an existing file; and an output that *is* an input (the same path, a symbolic or hard
//! link to it) is refused before anything is written, since the rename would replace the
//! input.

use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// The output would replace one of the run's inputs.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: the output is an input of this run ({}); choose another file", output.display(), input.display())]
pub struct OutputIsInput {
    /// The output asked for.
    pub output: PathBuf,
    /// The input it is (the same file, or a link to it).
    pub input: PathBuf,
}

/// Checks that `output` is none of `inputs` (same device and inode, links followed). An
/// output that does not exist yet is no input.
pub fn check_output(output: &Path, inputs: &[&Path]) -> Result<(), OutputIsInput> {
    let Ok(out) = std::fs::metadata(output) else {
        return Ok(());
    };
    for input in inputs {
        if let Ok(i) = std::fs::metadata(input)
            && (i.dev(), i.ino()) == (out.dev(), out.ino())
        {
            return Err(OutputIsInput {
                output: output.to_path_buf(),
                input: input.to_path_buf(),
            });
        }
    }
    Ok(())
}

/// A new file beside `path` to write it under until it is finished:
/// `NAME.PID.partial` (or `NAME.PID-N.partial` if that exists), created empty. A file
/// left by an earlier run that was killed is never reused.
pub fn create_partial(path: &Path) -> std::io::Result<(PathBuf, std::fs::File)> {
    if crate::shipped::find(path).is_some() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "a builtin: path names a file built into the binary, which is read-only: \
             write the output to a file",
        ));
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| std::io::Error::other("the output path has no file name"))?;
    let pid = std::process::id();
    let mut n = 0_u32;
    loop {
        let candidate = path.with_file_name(if n == 0 {
            format!("{name}.{pid}.partial")
        } else {
            format!("{name}.{pid}-{n}.partial")
        });
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&candidate)
        {
            Ok(file) => return Ok((candidate, file)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && n < 1000 => n += 1,
            Err(e) => return Err(e),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_output_linked_to_an_input_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let input = dir.path().join("in");
        std::fs::write(&input, b"x").expect("write");
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(&input, &link).expect("symlink");
        assert!(check_output(&input, &[&input]).is_err());
        assert!(check_output(&link, &[&input]).is_err());
        assert!(check_output(&dir.path().join("new"), &[&input]).is_ok());
        let other = dir.path().join("other");
        std::fs::write(&other, b"y").expect("write");
        assert!(check_output(&other, &[&input]).is_ok());
        // A built-in file is no place to write to.
        let e = create_partial(Path::new("builtin:recordings/byebye.mcap")).expect_err("refused");
        assert!(e.to_string().contains("built into the binary"), "{e}");
        assert!(create_partial(Path::new("builtin:out.mcap")).is_err());
    }

    #[test]
    fn partial_files_never_reuse_an_existing_name() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("out.mcap");
        let (a, _) = create_partial(&out).expect("first");
        let (b, _) = create_partial(&out).expect("second");
        assert_ne!(a, b);
        assert!(a.to_string_lossy().ends_with(".partial"));
    }
}
