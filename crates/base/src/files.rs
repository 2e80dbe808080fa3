//! Reading a user's file: one way for every format, so that no file can block, exhaust
//! memory or outlive a stop.
//!
//! [`open_regular`] opens only a regular file (a link is followed): a device such as
//! `/dev/zero`, a FIFO, a socket or a directory is refused with what it is, and a FIFO
//! is refused without waiting for a writer (it is opened non-blocking, then looked at).
//! [`read_capped`] reads at most the format's cap (a longer file is refused, not read),
//! in pieces between which a [`stop`] requested by a signal ends the read.

use std::fs::File;
use std::io::{self, Read};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// What a path names when it is not a regular file, in words (`None` for a regular file).
fn not_regular(kind: std::fs::FileType) -> Option<&'static str> {
    if kind.is_file() {
        None
    } else if kind.is_dir() {
        Some("a directory")
    } else if kind.is_fifo() {
        Some("a FIFO (named pipe)")
    } else if kind.is_char_device() {
        Some("a character device")
    } else if kind.is_block_device() {
        Some("a block device")
    } else if kind.is_socket() {
        Some("a socket")
    } else {
        Some("not a regular file")
    }
}

/// What `path` names (links followed) when it exists and is not a regular file, in
/// words: "a directory", "a FIFO (named pipe)", ...; `None` for a regular file or nothing.
pub fn what_is(path: &Path) -> Option<&'static str> {
    std::fs::metadata(path)
        .ok()
        .and_then(|m| not_regular(m.file_type()))
}

/// Opens `path` for reading if it is a regular file (links followed); anything else is
/// an [`io::ErrorKind::InvalidInput`] error that says what it is. Never blocks on a FIFO.
pub fn open_regular(path: &Path) -> io::Result<File> {
    // O_NONBLOCK: opening a FIFO does not wait for a writer; a regular file's reads
    // ignore the flag.
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)?;
    let metadata = file.metadata()?;
    if let Some(what) = not_regular(metadata.file_type()) {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{what}, not a regular file"),
        ));
    }
    inputs::note(&metadata, path);
    Ok(file)
}

/// Every file this process opened through [`open_regular`] (by device and inode, so a
/// link to one is the same file), once [`remember`] is called (the `posestream` command
/// does, at its start): an output is never written onto one of them, whichever option
/// named it (`posestream_msgs::files::check_output`). A library's user that rewrites a
/// file it read does not call it.
pub mod inputs {
    use std::collections::HashMap;
    use std::os::unix::fs::MetadataExt;
    use std::path::{Path, PathBuf};
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicBool, Ordering};

    /// Files remembered at most (a folder of more images is checked by the folder).
    pub const MAX_REMEMBERED: usize = 1 << 16;

    static REMEMBER: AtomicBool = AtomicBool::new(false);
    static READ: Mutex<Option<HashMap<(u64, u64), PathBuf>>> = Mutex::new(None);

    /// From now on, files read are remembered as this process's inputs.
    pub fn remember() {
        REMEMBER.store(true, Ordering::Relaxed);
    }

    pub(super) fn note(metadata: &std::fs::Metadata, path: &Path) {
        note_file((metadata.dev(), metadata.ino()), path);
    }

    /// Remembers the file with this device and inode, while fewer than
    /// [`MAX_REMEMBERED`] are; how many are.
    fn note_file(file: (u64, u64), path: &Path) -> usize {
        if !REMEMBER.load(Ordering::Relaxed) {
            return 0;
        }
        let mut read = READ.lock().unwrap_or_else(|e| e.into_inner());
        let read = read.get_or_insert_with(HashMap::new);
        if read.len() < MAX_REMEMBERED {
            read.entry(file).or_insert_with(|| path.to_path_buf());
        }
        read.len()
    }

    /// The path an input with this metadata was read under, if this process read it.
    pub fn read_as(metadata: &std::fs::Metadata) -> Option<PathBuf> {
        let read = READ.lock().unwrap_or_else(|e| e.into_inner());
        read.as_ref()?
            .get(&(metadata.dev(), metadata.ino()))
            .cloned()
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn at_most_so_many_inputs_are_remembered() {
            // Device u64::MAX: no real file's (this test's process remembers nothing else).
            remember();
            let path = Path::new("remembered");
            let counts: Vec<usize> = (0..MAX_REMEMBERED as u64 + 100)
                .map(|ino| note_file((u64::MAX, ino), path))
                .collect();
            assert_eq!(counts[0], 1);
            assert_eq!(counts.last(), Some(&MAX_REMEMBERED));
            // The ones remembered are still known; those beyond the cap are not.
            let read = READ.lock().unwrap_or_else(|e| e.into_inner());
            let read = read.as_ref().expect("remembered");
            assert!(read.contains_key(&(u64::MAX, 0)));
            assert!(!read.contains_key(&(u64::MAX, MAX_REMEMBERED as u64 + 50)));
        }
    }
}

/// Reads a regular file whole ([`open_regular`]), refusing one longer than `cap` bytes
/// ([`io::ErrorKind::InvalidData`], saying the cap)
/// without reading beyond it; a [`stop`] ends the read ([`io::ErrorKind::Interrupted`]).
pub fn read_capped(path: &Path, cap: u64) -> io::Result<Vec<u8>> {
    let file = open_regular(path)?;
    let size = file.metadata()?.len();
    if size > cap {
        return Err(too_long(cap));
    }
    let mut bytes = Vec::with_capacity(usize::try_from(size).unwrap_or(0));
    let mut limited = file.take(cap + 1);
    let mut piece = [0_u8; 64 << 10];
    loop {
        if stop::requested() {
            return Err(io::Error::new(
                io::ErrorKind::Interrupted,
                "stopped by a signal while reading",
            ));
        }
        match limited.read(&mut piece) {
            Ok(0) => break,
            Ok(n) => bytes.extend_from_slice(&piece[..n]),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    if bytes.len() as u64 > cap {
        return Err(too_long(cap));
    }
    Ok(bytes)
}

/// [`read_capped`] as UTF-8 text.
pub fn read_capped_string(path: &Path, cap: u64) -> io::Result<String> {
    String::from_utf8(read_capped(path, cap)?)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "not UTF-8 text"))
}

fn too_long(cap: u64) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("longer than {cap} bytes, the most this kind of file may have"),
    )
}

/// A process-wide stop, requested by a signal handler: reads of users' files end at
/// their next piece, and loops that look at it stop.
pub mod stop {
    use std::sync::atomic::{AtomicBool, Ordering};

    static REQUESTED: AtomicBool = AtomicBool::new(false);

    /// Asks everything that looks to stop (safe from a signal handler's thread).
    pub fn request() {
        REQUESTED.store(true, Ordering::Relaxed);
    }

    /// Whether a stop was asked for.
    pub fn requested() -> bool {
        REQUESTED.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_regular_files_are_read_and_only_up_to_the_cap() {
        let dir = std::env::temp_dir().join(format!("posestream-files-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let file = dir.join("a.txt");
        std::fs::write(&file, b"12345").expect("write");
        assert_eq!(read_capped(&file, 5).expect("reads"), b"12345");
        let e = read_capped(&file, 4).expect_err("too long");
        assert!(e.to_string().contains("longer than 4 bytes"), "{e}");
        for (path, what) in [
            (Path::new("/dev/zero"), "character device"),
            (dir.as_path(), "directory"),
        ] {
            let e = read_capped(path, 1 << 30).expect_err("not a file");
            assert_eq!(e.kind(), io::ErrorKind::InvalidInput);
            assert!(e.to_string().contains(what), "{e}");
        }
        // A link to a device is the device.
        let link = dir.join("zero");
        let _ = std::fs::remove_file(&link);
        std::os::unix::fs::symlink("/dev/zero", &link).expect("link");
        assert!(read_capped(&link, 1 << 30).is_err());
        // A FIFO without a writer: refused at once, not waited on.
        let fifo = dir.join("fifo");
        let _ = std::fs::remove_file(&fifo);
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            let e = open_regular(&fifo).expect_err("a FIFO");
            assert!(e.to_string().contains("FIFO"), "{e}");
        }
        // A stop asked for (by a signal) ends a read; no other test here reads.
        stop::request();
        let e = read_capped(&file, 5).expect_err("stopped");
        assert_eq!(e.kind(), io::ErrorKind::Interrupted);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
