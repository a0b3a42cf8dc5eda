//! The coordinator's typed errors and their one mapping to gRPC codes.

use crate::scheduler::SchedError;
use trevi_core::SceneError;

/// Why the farm refused or failed a request; [`FarmError::code`] is its
/// gRPC status code.
#[derive(Debug, thiserror::Error)]
pub enum FarmError {
    /// No job (or sequence) has this id (`NOT_FOUND`).
    #[error("no job {0}")]
    UnknownJob(u64),
    /// No registered worker has this id: it was forgotten after a long
    /// silence, or the coordinator restarted (`UNAUTHENTICATED`, which makes workers register again).
    #[error("unknown worker {0}; register again")]
    UnknownWorker(u64),
    /// No bundle has this hash on the coordinator (`NOT_FOUND`).
    #[error("no bundle {0}; upload it first")]
    UnknownBundle(String),
    /// Uploaded or stored bytes that are not a bundle the farm takes
    /// (`INVALID_ARGUMENT`).
    #[error("bad scene bundle: {0}")]
    BadBundle(String),
    /// A bundle whose scene cannot be rendered on the farm
    /// (`INVALID_ARGUMENT`).
    #[error("bad scene: {0}")]
    BadScene(BadScene),
    /// An upload that does not fit its lease: wrong rect, size, values or
    /// encoding (`INVALID_ARGUMENT`).
    #[error("tile rejected: {0}")]
    BadTile(String),
    /// A lease that is not (or no longer) the uploading worker's
    /// (`PERMISSION_DENIED`).
    #[error("tile refused: {0}")]
    NotYourLease(String),
    /// A request past one of the farm's bounds (`RESOURCE_EXHAUSTED`).
    #[error("{0}")]
    Limit(Limit),
    /// A request argument out of its range (`INVALID_ARGUMENT`).
    #[error("{0}")]
    Invalid(String),
    /// The job (or sequence, its id first) has no output to give yet, or
    /// not the one asked for (`FAILED_PRECONDITION`).
    #[error("job {0} has no output: {1}")]
    NoOutput(u64, String),
    /// The job is done, failed or cancelled, so it can no longer be
    /// changed (`FAILED_PRECONDITION`).
    #[error("job {0} is over")]
    JobOver(u64),
    /// The job is not in a state the request applies to (resuming a job
    /// that is not paused, pausing a frame of a sequence)
    /// (`FAILED_PRECONDITION`).
    #[error("{0}")]
    Conflict(String),
    /// Reading or writing the coordinator's own files or database failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done, naming the file or job.
        what: String,
        /// The underlying error (I/O, SQLite, …).
        source: BoxError,
    },
    /// Stored state that cannot be used as it is (a database SQLite would
    /// open by dropping what it holds, a stored tile outside its frame).
    #[error("{0}")]
    Damaged(String),
}

/// Why a scene cannot be rendered on the farm.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BadScene {
    /// The scene file or a file it references is wrong, with its file,
    /// line, column and kind (from the headers-only parse of admission).
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// What the farm refuses of a scene that parsed: a camera it does not
    /// have, an empty frame, an output name it cannot write.
    #[error("{0}")]
    Refused(String),
}

/// Which of the farm's bounds a request reached (see `docs/farm.md`,
/// "Limits").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LimitKind {
    /// Samples of one frame (`--max-image-samples`).
    ImageSamples,
    /// Tiles of one job (`u32::MAX`, no flag).
    JobTiles,
    /// Bytes of one band of tiles against the per-job window (`--window-mib`).
    Window,
    /// Unfinished jobs of one submitter (`--max-jobs-per-submitter`).
    JobsPerSubmitter,
    /// Workers registered at once (`--max-workers`).
    Workers,
    /// Workers registered from one address (`--max-workers-per-address`).
    WorkersPerAddress,
    /// Scenes admitted at once (`--max-admissions`).
    Admissions,
    /// Bytes of the admissions in progress (`--admission-mib`).
    AdmissionBytes,
    /// Files in one bundle (`--max-bundle-files`).
    BundleFiles,
    /// Pixels of one tile of a progressive job, whose lease carries its
    /// state (`Limits::max_state_lease_pixels`, no flag).
    StateLeasePixels,
    /// Bytes of a progressive job's states on disk
    /// (`Limits::max_job_state_bytes`, no flag).
    JobStateBytes,
}

impl LimitKind {
    /// The flag that sets the bound; `None` for a fixed one.
    pub fn flag(self) -> Option<&'static str> {
        Some(match self {
            LimitKind::ImageSamples => "--max-image-samples",
            LimitKind::JobTiles | LimitKind::StateLeasePixels | LimitKind::JobStateBytes => {
                return None
            }
            LimitKind::Window => "--window-mib",
            LimitKind::JobsPerSubmitter => "--max-jobs-per-submitter",
            LimitKind::Workers => "--max-workers",
            LimitKind::WorkersPerAddress => "--max-workers-per-address",
            LimitKind::Admissions => "--max-admissions",
            LimitKind::AdmissionBytes => "--admission-mib",
            LimitKind::BundleFiles => "--max-bundle-files",
        })
    }
}

/// A request refused at one of the farm's bounds: which bound, what was
/// asked and the bound, in that limit's unit; shown as the sentence users
/// see (`RESOURCE_EXHAUSTED`), which names the flag.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct Limit {
    /// Which bound.
    pub kind: LimitKind,
    /// What the request needed (for a count of things held at once, the
    /// count already held).
    pub asked: u64,
    /// The bound.
    pub bound: u64,
    message: String,
}

impl Limit {
    /// The flag that sets the bound (see [`LimitKind::flag`]).
    pub fn flag(&self) -> Option<&'static str> {
        self.kind.flag()
    }
}

/// The underlying error of [`FarmError::Io`]: an I/O, database, image or
/// random-source error, kept whole.
pub type BoxError = Box<dyn std::error::Error + Send + Sync>;

impl FarmError {
    /// [`FarmError::Io`]: `what` failed because of `source`.
    pub fn io(what: impl Into<String>, source: impl Into<BoxError>) -> FarmError {
        FarmError::Io {
            what: what.into(),
            source: source.into(),
        }
    }
}

impl FarmError {
    /// [`FarmError::BadScene`] for what the farm refuses of a parsed scene.
    pub fn refused_scene(why: impl Into<String>) -> FarmError {
        FarmError::BadScene(BadScene::Refused(why.into()))
    }

    /// [`FarmError::Limit`]: `kind`'s bound reached, `asked` against
    /// `bound`; `message` is what users read, naming the flag.
    pub fn limit(kind: LimitKind, asked: u64, bound: u64, message: impl Into<String>) -> FarmError {
        FarmError::Limit(Limit {
            kind,
            asked,
            bound,
            message: message.into(),
        })
    }
}

impl From<SceneError> for FarmError {
    fn from(e: SceneError) -> Self {
        FarmError::BadScene(BadScene::Scene(e))
    }
}

impl From<SchedError> for FarmError {
    fn from(e: SchedError) -> Self {
        match e {
            SchedError::UnknownJob(j) => FarmError::UnknownJob(j),
            SchedError::UnknownWorker(w) => FarmError::UnknownWorker(w),
            e @ SchedError::NotATile(..) => FarmError::BadTile(e.to_string()),
            e @ (SchedError::NotYourLease(..) | SchedError::NotHeld(..)) => {
                FarmError::NotYourLease(e.to_string())
            }
            SchedError::JobOver(j) => FarmError::JobOver(j),
            e @ SchedError::NotBlocked { .. } => FarmError::Conflict(e.to_string()),
        }
    }
}

impl FarmError {
    /// The gRPC status code the error is answered with.
    pub fn code(&self) -> tonic::Code {
        use tonic::Code;
        match self {
            FarmError::UnknownJob(_) | FarmError::UnknownBundle(_) => Code::NotFound,
            // Workers re-register when they see this code.
            FarmError::UnknownWorker(_) => Code::Unauthenticated,
            FarmError::BadBundle(_) | FarmError::BadScene(_) | FarmError::BadTile(_) => {
                Code::InvalidArgument
            }
            FarmError::NoOutput(..) | FarmError::JobOver(_) | FarmError::Conflict(_) => {
                Code::FailedPrecondition
            }
            FarmError::NotYourLease(_) => Code::PermissionDenied,
            FarmError::Limit(_) => Code::ResourceExhausted,
            FarmError::Invalid(_) => Code::InvalidArgument,
            // Out of descriptors or memory: it passes, try again.
            FarmError::Io { source, .. } if is_exhaustion(source.as_ref()) => Code::Unavailable,
            FarmError::Io { .. } | FarmError::Damaged(_) => Code::Internal,
        }
    }
}

/// Whether an I/O error is the process or the system running out of a
/// resource that frees up (open files, memory): `UNAVAILABLE`, not a fault.
fn is_exhaustion(e: &(dyn std::error::Error + 'static)) -> bool {
    e.downcast_ref::<std::io::Error>()
        .and_then(std::io::Error::raw_os_error)
        .is_some_and(|c| [libc::EMFILE, libc::ENFILE, libc::ENOMEM, libc::EAGAIN].contains(&c))
}

impl From<FarmError> for tonic::Status {
    fn from(e: FarmError) -> Self {
        tonic::Status::new(e.code(), e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tonic::Code;

    #[test]
    fn errors_map_to_grpc_codes_and_keep_their_message() {
        let cases = [
            (FarmError::UnknownJob(3), Code::NotFound),
            (FarmError::UnknownBundle("ab".into()), Code::NotFound),
            (FarmError::UnknownWorker(9), Code::Unauthenticated),
            (FarmError::BadBundle("x".into()), Code::InvalidArgument),
            (FarmError::refused_scene("x"), Code::InvalidArgument),
            (FarmError::BadTile("x".into()), Code::InvalidArgument),
            (FarmError::NoOutput(1, "x".into()), Code::FailedPrecondition),
            (FarmError::JobOver(1), Code::FailedPrecondition),
            (FarmError::io("x", "y"), Code::Internal),
            (FarmError::Damaged("x".into()), Code::Internal),
            (FarmError::NotYourLease("x".into()), Code::PermissionDenied),
            (
                FarmError::limit(LimitKind::Workers, 2, 2, "x"),
                Code::ResourceExhausted,
            ),
        ];
        for (e, code) in cases {
            let msg = e.to_string();
            let status = tonic::Status::from(e);
            assert_eq!(status.code(), code);
            assert_eq!(status.message(), msg);
        }
        let e = FarmError::io("opening f", std::io::Error::from_raw_os_error(libc::EMFILE));
        assert_eq!(e.code(), Code::Unavailable);
        let e = FarmError::io("opening f", std::io::Error::from_raw_os_error(libc::EACCES));
        assert_eq!(e.code(), Code::Internal);
        let e = FarmError::io("reading f", std::io::Error::other("gone"));
        assert_eq!(e.to_string(), "reading f: gone");
        assert!(std::error::Error::source(&e).is_some(), "the cause is kept");
        // A scene error keeps its place and kind, and reads as it did.
        let scene = SceneError::of_kind(
            trevi_core::SceneErrorKind::BadValue,
            trevi_core::Location::new("s.xml", 3, 7),
            "no",
        );
        let e = FarmError::from(scene.clone());
        assert_eq!(e.to_string(), format!("bad scene: {scene}"));
        assert!(matches!(&e, FarmError::BadScene(BadScene::Scene(s)) if s == &scene));
        assert_eq!(e.code(), Code::InvalidArgument);
        let e = FarmError::limit(LimitKind::Admissions, 4, 4, "4 at once (--max-admissions)");
        assert_eq!(e.to_string(), "4 at once (--max-admissions)");
        assert!(matches!(&e, FarmError::Limit(l) if l.flag() == Some("--max-admissions")));
        let e: FarmError = SchedError::UnknownWorker(4).into();
        assert!(matches!(e, FarmError::UnknownWorker(4)));
    }
}
