//! Output files of a run: never one of its inputs.
//!
//! Outputs are written under a temporary name and renamed into place when finished
//! ([`crate::recording::Recorder`], [`crate::npy::write`]), so a failed run never destroys
//! an existing file; and an output that *is* an input (the same path, a symbolic or hard
//! link to it) is refused before anything is written, since the rename would replace the
//! input.

use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// The prefix of a path that names a file built into the binary (`crate::shipped`).
pub const BUILTIN: &str = "builtin:";

/// The output would replace one of the run's inputs.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: the output is an input of this run ({}); choose another file", output.display(), input.display())]
pub struct OutputIsInput {
    /// The output asked for.
    pub output: PathBuf,
    /// The input it is (the same file, or a link to it).
    pub input: PathBuf,
}

/// Checks that `output` is none of `inputs`, nor any file this process has read
/// ([`posestream_base::files::inputs`]): same device and inode, links followed. An
/// output that does not exist yet is no input.
pub fn check_output(output: &Path, inputs: &[&Path]) -> Result<(), OutputIsInput> {
    let Ok(out) = std::fs::metadata(output) else {
        return Ok(());
    };
    if let Some(input) = posestream_base::files::inputs::read_as(&out) {
        return Err(OutputIsInput {
            output: output.to_path_buf(),
            input,
        });
    }
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
    // `builtin:` names a file built into the binary (`crate::shipped`), never one to write.
    if path.to_str().is_some_and(|p| p.starts_with(BUILTIN)) {
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

/// Why an output could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The output is one of the run's inputs.
    #[error(transparent)]
    IsInput(#[from] OutputIsInput),
    /// Writing it failed (the file it would replace is unchanged).
    #[error("{}: {}", path.display(), io_text(source))]
    Io {
        /// The output asked for.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
}

/// An I/O error in words, a full disk, quota or file-size limit named as such.
pub fn io_text(e: &std::io::Error) -> String {
    use std::io::ErrorKind;
    match e.kind() {
        ErrorKind::StorageFull => {
            "no space left on the device (the disk or the file system is full)".into()
        }
        ErrorKind::QuotaExceeded => "the disk quota is exhausted".into(),
        ErrorKind::FileTooLarge => "the file is larger than this process may write \
                                    (`ulimit -f`) or the file system allows"
            .into(),
        _ => e.to_string(),
    }
}

/// Checks, before any work, that `path` can be an output: none of `inputs` nor of the
/// files read ([`check_output`]), and not a device, a FIFO or a directory (the rename
/// would put a file where one was).
pub fn check_target(path: &Path, inputs: &[&Path]) -> Result<(), OutputError> {
    check_output(path, inputs)?;
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
        return Err(OutputError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "is not a regular file (a device, a FIFO or a directory): give a file's path",
            ),
        });
    }
    Ok(())
}

/// Checks that `output` is none of `others`, the run's other outputs (the same path, or
/// the same file through a link): one would be written over the other.
pub fn check_distinct(output: &Path, others: &[&Path]) -> Result<(), OutputError> {
    let same_path = |other: &Path| match (std::path::absolute(output), std::path::absolute(other)) {
        (Ok(a), Ok(b)) => a == b,
        _ => output == other,
    };
    let same_file = |other: &Path| match (std::fs::metadata(output), std::fs::metadata(other)) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    };
    match others.iter().find(|o| same_path(o) || same_file(o)) {
        Some(other) => Err(OutputError::Io {
            path: output.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "is also another output of this run ({}): give each output a file of its own",
                    other.display()
                ),
            ),
        }),
        None => Ok(()),
    }
}

/// An output file written under a temporary name beside its path ([`create_partial`]) and
/// renamed into place by [`OutputFile::commit`]: an output that is an input is refused
/// before anything is written, and a run that fails (or a full disk) leaves the existing
/// file as it was. Dropped without a commit, the temporary file is removed.
pub struct OutputFile {
    path: PathBuf,
    partial: PathBuf,
    file: Option<std::io::BufWriter<std::fs::File>>,
}

impl OutputFile {
    /// Starts writing `path`, none of `inputs`.
    pub fn create(path: &Path, inputs: &[&Path]) -> Result<Self, OutputError> {
        check_target(path, inputs)?;
        let (partial, file) = create_partial(path).map_err(|source| OutputError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(Self {
            path: path.to_path_buf(),
            partial,
            file: Some(std::io::BufWriter::new(file)),
        })
    }

    /// Where it is written until [`OutputFile::commit`].
    pub fn writer(&mut self) -> &mut std::io::BufWriter<std::fs::File> {
        self.file.as_mut().expect("present until committed")
    }

    /// Flushes, syncs and renames the file into place.
    pub fn commit(mut self) -> Result<(), OutputError> {
        let io = |source| OutputError::Io {
            path: self.path.clone(),
            source,
        };
        let file = self.file.take().expect("present until committed");
        let file = file.into_inner().map_err(|e| io(e.into_error()))?;
        file.sync_all().map_err(io)?;
        drop(file);
        std::fs::rename(&self.partial, &self.path).map_err(io)?;
        if let Some(dir) = self.path.parent().filter(|d| !d.as_os_str().is_empty())
            && let Ok(d) = std::fs::File::open(dir)
        {
            let _ = d.sync_all();
        }
        Ok(())
    }
}

impl Drop for OutputFile {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            let _ = std::fs::remove_file(&self.partial);
        }
    }
}

/// Writes `bytes` to `path` through an [`OutputFile`].
pub fn write_output(path: &Path, inputs: &[&Path], bytes: &[u8]) -> Result<(), OutputError> {
    let mut out = OutputFile::create(path, inputs)?;
    std::io::Write::write_all(out.writer(), bytes).map_err(|source| OutputError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    out.commit()
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
    fn an_output_is_renamed_into_place_and_a_link_to_an_input_is_left_alone() {
        let dir = tempfile::tempdir().expect("tempdir");
        let input = dir.path().join("in");
        std::fs::write(&input, b"input").expect("write");
        let hard = dir.path().join("hard");
        std::fs::hard_link(&input, &hard).expect("link");
        assert!(matches!(
            write_output(&hard, &[&input], b"out"),
            Err(OutputError::IsInput(_))
        ));
        let out = dir.path().join("out");
        write_output(&out, &[&input], b"out").expect("writes");
        assert_eq!(std::fs::read(&out).expect("read"), b"out");
        // Not committed: the old file stays, no temporary file is left.
        let mut unfinished = OutputFile::create(&out, &[&input]).expect("starts");
        std::io::Write::write_all(unfinished.writer(), b"half").expect("write");
        drop(unfinished);
        assert_eq!(std::fs::read(&out).expect("read"), b"out");
        assert_eq!(std::fs::read_dir(dir.path()).expect("dir").count(), 3);
        assert_eq!(std::fs::read(&input).expect("read"), b"input");
        let full = std::io::Error::from_raw_os_error(28);
        assert!(
            io_text(&full).contains("no space left"),
            "{}",
            io_text(&full)
        );
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
