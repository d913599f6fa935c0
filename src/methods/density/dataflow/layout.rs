//! Where the workers of a dataflow bake run: threads, or processes named
//! by a host file; and the errors of a dataflow bake.

use std::path::{Path, PathBuf};
use std::sync::{Mutex, Once};

use timely::CommunicationConfig;

use crate::methods::density::DensityError;

/// How the workers of a dataflow bake are laid out.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Workers {
    /// Worker threads in this process.
    Threads(usize),
    /// One of several processes (timely's cluster configuration).
    Cluster {
        /// Worker threads in each process.
        threads: usize,
        /// This process's index, from 0.
        process: usize,
        /// `host:port` of every process, in process order.
        addresses: Vec<String>,
    },
}

impl Workers {
    /// The processes of a cluster bake from the command line: this one is
    /// `process` of `processes`, the addresses are the lines of `hostfile`.
    pub fn cluster(
        threads: usize,
        process: usize,
        processes: usize,
        hostfile: &Path,
    ) -> Result<Workers, DataflowError> {
        if threads == 0 {
            return Err(DataflowError::NoWorkers);
        }
        if process >= processes {
            return Err(DataflowError::ProcessIndex {
                index: process,
                count: processes,
            });
        }
        let addresses = read_hostfile(hostfile)?;
        if addresses.len() != processes {
            return Err(DataflowError::HostCount {
                path: hostfile.to_path_buf(),
                found: addresses.len(),
                expected: processes,
            });
        }
        Ok(Workers::Cluster {
            threads,
            process,
            addresses,
        })
    }

    /// Workers in all processes.
    pub fn total(&self) -> usize {
        match self {
            Workers::Threads(n) => *n,
            Workers::Cluster {
                threads, addresses, ..
            } => threads * addresses.len(),
        }
    }

    /// The address of process `i` of a cluster.
    pub fn address(&self, i: usize) -> Option<&str> {
        match self {
            Workers::Threads(_) => None,
            Workers::Cluster { addresses, .. } => addresses.get(i).map(String::as_str),
        }
    }

    pub(super) fn config(&self) -> Result<CommunicationConfig, DataflowError> {
        match self {
            Workers::Threads(0) => Err(DataflowError::NoWorkers),
            Workers::Threads(n) => Ok(CommunicationConfig::Process(*n)),
            Workers::Cluster {
                threads,
                process,
                addresses,
            } => Ok(CommunicationConfig::Cluster {
                threads: *threads,
                process: *process,
                addresses: addresses.clone(),
                report: false,
                zerocopy: false,
            }),
        }
    }
}

/// Reads a host file: one `host:port` a line, in process order; blank
/// lines and lines starting with `#` are skipped.
pub fn read_hostfile(path: &Path) -> Result<Vec<String>, DataflowError> {
    let text = std::fs::read_to_string(path).map_err(|source| DataflowError::HostRead {
        path: path.to_path_buf(),
        source,
    })?;
    let mut hosts = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let ok = l
            .rsplit_once(':')
            .is_some_and(|(h, p)| !h.is_empty() && p.parse::<u16>().is_ok_and(|p| p > 0));
        if !ok || l.contains(char::is_whitespace) {
            return Err(DataflowError::HostLine {
                path: path.to_path_buf(),
                line: i + 1,
                text: l.to_string(),
            });
        }
        hosts.push(l.to_string());
    }
    Ok(hosts)
}

/// Panics of timely's network threads (named `timely:recv-N` and
/// `timely:send-N`, N the remote process), recorded by the hook of
/// [`watch_network`]: the remote process and the message.
static LOST: Mutex<Vec<(usize, String)>> = Mutex::new(Vec::new());

/// Installs (once) a panic hook that records the panics of timely's
/// network threads instead of printing them: a lost connection to process
/// N ends its threads with a panic, which the bake reports as an error
/// naming N ([`lost_peer`]). Other panics go to the hook before. Forgets
/// what was recorded before.
pub(super) fn watch_network() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let prev = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let thread = std::thread::current();
            let remote = thread
                .name()
                .and_then(|n| {
                    n.strip_prefix("timely:recv-")
                        .or_else(|| n.strip_prefix("timely:send-"))
                })
                .and_then(|i| i.parse::<usize>().ok());
            let Some(remote) = remote else {
                return prev(info);
            };
            let p = info.payload();
            let msg = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "the connection failed".into());
            LOST.lock()
                .unwrap_or_else(|e| e.into_inner())
                .push((remote, msg));
        }));
    });
    LOST.lock().unwrap_or_else(|e| e.into_inner()).clear();
}

/// The first connection lost since [`watch_network`]: the remote process
/// and why.
pub(super) fn lost_peer() -> Option<(usize, String)> {
    LOST.lock()
        .unwrap_or_else(|e| e.into_inner())
        .first()
        .cloned()
}

/// An error of a dataflow bake.
#[derive(Debug, thiserror::Error)]
pub enum DataflowError {
    /// The host file cannot be read.
    #[error("cannot read the host file {}", path.display())]
    HostRead {
        /// The file.
        path: PathBuf,
        /// Why not.
        #[source]
        source: std::io::Error,
    },
    /// A host-file line is not `host:port`.
    #[error("{}:{line}: expected host:port (a port from 1 to 65535), got '{text}'", path.display())]
    HostLine {
        /// The file.
        path: PathBuf,
        /// Line number, from 1.
        line: usize,
        /// The line.
        text: String,
    },
    /// The host file lists another number of processes.
    #[error("the host file {} lists {found} hosts, but --processes is {expected}", path.display())]
    HostCount {
        /// The file.
        path: PathBuf,
        /// Hosts listed.
        found: usize,
        /// --processes.
        expected: usize,
    },
    /// The process index is out of range.
    #[error(
        "--process {index} is out of range: --processes is {count} (processes are numbered from 0)"
    )]
    ProcessIndex {
        /// --process.
        index: usize,
        /// --processes.
        count: usize,
    },
    /// No workers.
    #[error("--workers must be at least 1")]
    NoWorkers,
    /// timely could not set up its communication (a port in use, ...).
    #[error("cannot start the dataflow: {0}")]
    Network(String),
    /// Another worker failed; its reason.
    #[error("worker {worker} failed: {reason}")]
    Peer {
        /// The worker's global index.
        worker: usize,
        /// What it reported.
        reason: String,
    },
    /// The connection to another process was lost (it died, or the network
    /// between failed).
    #[error("lost the connection to process {process} ({address}): {cause}")]
    Lost {
        /// The process's index.
        process: usize,
        /// Its address, from the host file.
        address: String,
        /// What the network thread reported.
        cause: String,
    },
    /// A worker thread panicked (a lost connection to a peer process ends
    /// timely's network thread with a panic).
    #[error("a dataflow worker stopped: {0}")]
    Worker(String),
    /// The bake itself, at this worker.
    #[error(transparent)]
    Density(#[from] DensityError),
}
