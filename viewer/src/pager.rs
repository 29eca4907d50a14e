//! Background loading: worker threads read and decode chunk files in order
//! of priority (the screen error of the chunk that waits for them), and the
//! render thread collects what is done without ever waiting for it.
//!
//! Each frame the render thread hands over the whole list of chunks the
//! selection still wants ([`Pager::request`]); queued requests that are no
//! longer wanted are dropped, so the queue follows the camera. At most
//! `max_pending` chunks are in flight or decoded-but-not-uploaded at once,
//! which bounds the CPU memory the pager holds.

use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use crate::scene::{ChunkMesh, load_chunk_under};

/// One chunk to load.
#[derive(Clone, Debug, PartialEq)]
pub struct Load {
    /// Node index.
    pub node: usize,
    /// Priority (higher first): the screen error that waits for it.
    pub priority: f64,
    /// Its file.
    pub path: PathBuf,
    /// Its parent's file, whose normals its vertices morph toward.
    pub parent: Option<PathBuf>,
}

struct Queue {
    /// Not yet started, lowest priority first.
    waiting: Vec<Load>,
    /// Workers wait while this is set (tests: loads that never finish).
    paused: bool,
    stop: bool,
}

struct Shared {
    queue: Mutex<Queue>,
    wake: Condvar,
}

/// Loads chunks on background threads.
pub struct Pager {
    shared: Arc<Shared>,
    done: Receiver<(usize, Result<ChunkMesh, String>)>,
    workers: Vec<JoinHandle<()>>,
    /// Nodes queued or being decoded.
    in_flight: HashSet<usize>,
    /// Decoded, waiting to be uploaded.
    ready: HashMap<usize, ChunkMesh>,
    /// Nodes whose file failed to load (never asked for again).
    failed: HashMap<usize, String>,
    max_pending: usize,
}

impl Pager {
    /// Starts `threads` workers (≥ 1); `max_pending` ≥ 1.
    pub fn new(threads: usize, max_pending: usize) -> Self {
        let shared = Arc::new(Shared {
            queue: Mutex::new(Queue { waiting: Vec::new(), paused: false, stop: false }),
            wake: Condvar::new(),
        });
        let (tx, done) = channel();
        let workers = (0..threads.max(1))
            .map(|_| {
                let (shared, tx): (Arc<Shared>, Sender<_>) = (shared.clone(), tx.clone());
                std::thread::spawn(move || worker(&shared, &tx))
            })
            .collect();
        Pager {
            shared,
            done,
            workers,
            in_flight: HashSet::new(),
            ready: HashMap::new(),
            failed: HashMap::new(),
            max_pending: max_pending.max(1),
        }
    }

    /// Replaces the queue with `wanted`, most wanted first (the order
    /// given, which the workers keep); never blocks on I/O.
    pub fn request(&mut self, wanted: &[Load]) {
        let mut q = self.shared.queue.lock().expect("pager lock");
        // Requests still queued but no longer wanted are dropped.
        for l in q.waiting.drain(..) {
            self.in_flight.remove(&l.node);
        }
        let mut room = self.max_pending.saturating_sub(self.in_flight.len() + self.ready.len());
        for l in wanted {
            if room == 0 {
                break;
            }
            let n = &l.node;
            if self.in_flight.contains(n) || self.ready.contains_key(n) || self.failed.contains_key(n) {
                continue;
            }
            q.waiting.push(l.clone());
            self.in_flight.insert(*n);
            room -= 1;
        }
        // Workers pop from the end.
        q.waiting.reverse();
        drop(q);
        self.shared.wake.notify_all();
    }

    /// Collects finished loads (non-blocking).
    pub fn poll(&mut self) {
        while let Ok((n, r)) = self.done.try_recv() {
            self.finish(n, r);
        }
    }

    /// Waits until nothing is queued or decoding (or `timeout` passes):
    /// tests that fix how many frames a load takes. Never inside a frame.
    pub fn wait_idle(&mut self, timeout: Duration) -> bool {
        let until = std::time::Instant::now() + timeout;
        while !self.in_flight.is_empty() {
            let left = until.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() || !self.wait(left) {
                return false;
            }
        }
        true
    }

    /// Waits up to `timeout` for one load to finish: for settling a still
    /// camera (screenshots, tests), never called inside a frame.
    pub fn wait(&mut self, timeout: Duration) -> bool {
        match self.done.recv_timeout(timeout) {
            Ok((n, r)) => {
                self.finish(n, r);
                self.poll();
                true
            }
            Err(_) => false,
        }
    }

    fn finish(&mut self, n: usize, r: Result<ChunkMesh, String>) {
        self.in_flight.remove(&n);
        match r {
            Ok(m) => {
                self.ready.insert(n, m);
            }
            Err(e) => {
                eprintln!("terrachunk-view: {e}");
                self.failed.insert(n, e);
            }
        }
    }

    /// Decoded chunks waiting for upload.
    pub fn ready(&mut self) -> &mut HashMap<usize, ChunkMesh> {
        &mut self.ready
    }

    /// Loads queued or decoding (the "pending loads" of the stats).
    pub fn pending(&self) -> usize {
        self.in_flight.len()
    }

    /// Files that failed to load.
    pub fn failed(&self) -> &HashMap<usize, String> {
        &self.failed
    }

    /// Holds (true) or releases (false) the workers before they start a
    /// load: a test's way of making loads slow without timing anything.
    pub fn set_paused(&self, paused: bool) {
        self.shared.queue.lock().expect("pager lock").paused = paused;
        self.shared.wake.notify_all();
    }
}

impl Drop for Pager {
    fn drop(&mut self) {
        {
            let mut q = self.shared.queue.lock().expect("pager lock");
            q.stop = true;
            q.waiting.clear();
        }
        self.shared.wake.notify_all();
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

fn worker(shared: &Shared, tx: &Sender<(usize, Result<ChunkMesh, String>)>) {
    loop {
        let load = {
            let mut q = shared.queue.lock().expect("pager lock");
            loop {
                if q.stop {
                    return;
                }
                if !q.paused
                    && let Some(l) = q.waiting.pop()
                {
                    break l;
                }
                q = shared.wake.wait(q).expect("pager lock");
            }
        };
        let r = load_chunk_under(&load.path, load.parent.as_deref()).map_err(|e| format!("{e:#}"));
        if tx.send((load.node, r)).is_err() {
            return;
        }
    }
}
