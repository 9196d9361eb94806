//! The package's thread pool: every kernel runs on it with the GIL released.
//!
//! A process forked from one whose pool was running (PyTorch `DataLoader` workers, forked by
//! default on Linux) inherits the pool's bookkeeping but none of its threads: work sent to it
//! would wait forever. The pool therefore remembers the process that made it, and a forked
//! child makes its own on first use; the parent's is forgotten there, never dropped (dropping
//! would wait on threads that do not exist in the child).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use pyo3::prelude::*;
use rayon::ThreadPool;

use crate::errors;

/// The thread count asked for; 0 = one per core the process may use.
static WANTED: AtomicUsize = AtomicUsize::new(0);

struct Pool {
    pid: u32,
    threads: usize,
    pool: Arc<ThreadPool>,
}

static POOL: Mutex<Option<Pool>> = Mutex::new(None);

/// The most threads [`set_threads`] takes.
const MAX_THREADS: usize = 1024;

fn wanted() -> usize {
    match WANTED.load(Ordering::Relaxed) {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    }
}

/// This process's pool with the wanted thread count, made on first use (or after a fork, or
/// after the count changed).
///
/// The lock is held only to read or swap the slot, never while a pool starts its threads, so a
/// fork from another thread almost never finds it held.
fn pool() -> PyResult<Arc<ThreadPool>> {
    let pid = std::process::id();
    let threads = wanted();
    {
        let slot = POOL.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(p) = slot.as_ref()
            && p.pid == pid
            && p.threads == threads
        {
            return Ok(p.pool.clone());
        }
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("neuspike-{i}"))
        .build()
        .map_err(|e| errors::config(format!("threads = {threads}: cannot start the pool: {e}")))?;
    let pool = Arc::new(pool);
    let old = POOL
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .replace(Pool {
            pid,
            threads,
            pool: pool.clone(),
        });
    if let Some(old) = old
        && old.pid != pid
    {
        // Made before a fork: its threads live only in the parent.
        std::mem::forget(old);
    }
    Ok(pool)
}

/// Runs `f` on the pool with the GIL released.
pub fn run<T: Send>(py: Python<'_>, f: impl FnOnce() -> T + Send) -> PyResult<T> {
    let pool = pool()?;
    Ok(py.detach(|| pool.install(f)))
}

/// Sets how many threads the kernels use (0: one per core the process may use, the default).
///
/// Takes effect at the next call; a kernel already running keeps its threads.
#[pyfunction]
pub fn set_threads(n: usize) -> PyResult<()> {
    if n > MAX_THREADS {
        return Err(errors::config(format!(
            "threads = {n}: at most {MAX_THREADS} (0 = one per core)"
        )));
    }
    WANTED.store(n, Ordering::Relaxed);
    Ok(())
}

/// How many threads the kernels use.
#[pyfunction]
pub fn threads() -> usize {
    wanted()
}
