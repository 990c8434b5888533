//! The library's error type. Every error that comes from user input names the file or the
//! option at fault; the CLI maps [`Error::is_user_error`] to exit code 2 and the rest to 1.

use std::path::{Path, PathBuf};

/// Result alias used across the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Every error of the library, by whose fault it is: [`Error::Io`], [`Error::Input`] and
/// [`Error::Usage`] are the user's (exit code 2), [`Error::Internal`] is not (exit code 1).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The file could not be opened, read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file at fault.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// The file was read but its content is unusable (corrupt, wrong format, wrong size, NaN...).
    #[error("{}: {msg}", path.display())]
    Input {
        /// The file at fault.
        path: PathBuf,
        /// What is wrong with its content.
        msg: String,
    },
    /// A parameter (flag, config key) is invalid; the message names it.
    #[error("{0}")]
    Usage(String),
    /// A bug or an environment failure that is not the user's input.
    #[error("internal error: {0}")]
    Internal(String),
}

impl Error {
    /// An [`Error::Io`] on `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io { path: path.as_ref().to_path_buf(), source }
    }

    /// An [`Error::Input`]: `path`'s content is unusable because of `msg`.
    pub fn input(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Input { path: path.as_ref().to_path_buf(), msg: msg.into() }
    }

    /// An [`Error::Usage`]; `msg` names the parameter (config key) at fault.
    pub fn usage(msg: impl Into<String>) -> Self {
        Error::Usage(msg.into())
    }

    /// This error with `what` (the part of the file at fault) in front of an input error's
    /// message; the file stays the one named. Other errors are returned as they are.
    pub(crate) fn within(self, what: &str) -> Self {
        match self {
            Error::Input { path, msg } => Error::Input { path, msg: format!("{what}: {msg}") },
            other => other,
        }
    }

    /// True when the error is caused by the user's input or options (exit code 2).
    pub fn is_user_error(&self) -> bool {
        !matches!(self, Error::Internal(_))
    }
}
