//! Perception's share of the CPU: the priority its threads run at, and the
//! CPU time the process uses (what `humem bench perception` reports).
//!
//! On the vehicle PC the SLAM threads must win.
//! ORB-SLAM3's tracking and local mapping run beside HuMem on the same
//! cores; a keyframe's inferences take tens of core-milliseconds, and at
//! the same priority they delay tracking enough to lose frames. Linux keeps
//! a nice value per thread and a new thread inherits its creator's, so
//! perception loads its models on a thread whose nice value is raised
//! first: ONNX Runtime's intra-op pools and the model worker threads are
//! all created from it and run at that priority, while the gRPC service and
//! the store keep theirs. A thread may always lower its own priority;
//! raising it back needs privileges, which is why the loading happens on a
//! thread of its own.

use std::io;

/// Highest nice value Linux accepts (the lowest priority).
pub const MAX_NICE: i32 = 19;

/// Raises the calling thread's nice value to `nice` (0 keeps it; a value
/// below the thread's current one is refused by Linux without
/// `CAP_SYS_NICE`).
#[cfg(target_os = "linux")]
pub fn set_this_thread_nice(nice: i32) -> io::Result<()> {
    if nice == 0 {
        return Ok(());
    }
    // SAFETY: gettid and setpriority take plain integers and touch no
    // memory of this process; PRIO_PROCESS with a thread id addresses that
    // one thread on Linux.
    #[allow(unsafe_code)]
    let status = unsafe {
        let tid = libc::gettid();
        libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, nice)
    };
    if status == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// Other systems: only 0 is accepted.
#[cfg(not(target_os = "linux"))]
pub fn set_this_thread_nice(nice: i32) -> io::Result<()> {
    if nice == 0 {
        Ok(())
    } else {
        Err(io::Error::new(
            io::ErrorKind::Unsupported,
            "perception.nice is supported on Linux only",
        ))
    }
}

/// Runs `f` on a new thread whose nice value is `nice`, so that every
/// thread `f` starts inherits it; returns what `f` returns.
pub fn run_at_nice<T: Send>(nice: i32, f: impl FnOnce() -> T + Send) -> io::Result<T> {
    if nice == 0 {
        return Ok(f());
    }
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .name("humem-perception-load".into())
            .spawn_scoped(scope, || {
                set_this_thread_nice(nice)?;
                Ok(f())
            })?
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
    })
}

/// CPU time this process has used so far (user and system, all threads),
/// from `getrusage`.
#[cfg(unix)]
pub fn process_cpu_time() -> std::time::Duration {
    // SAFETY: getrusage writes one rusage struct into the zeroed memory it
    // is given and reads nothing else.
    #[allow(unsafe_code)]
    let usage = unsafe {
        let mut usage = std::mem::zeroed::<libc::rusage>();
        libc::getrusage(libc::RUSAGE_SELF, &mut usage);
        usage
    };
    let time =
        |t: libc::timeval| std::time::Duration::new(t.tv_sec as u64, t.tv_usec as u32 * 1000);
    time(usage.ru_utime) + time(usage.ru_stime)
}

/// One thread of a process, as `/proc` shows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ThreadInfo {
    /// Thread id.
    pub tid: u32,
    /// Its name (`comm`, at most 15 bytes).
    pub name: String,
    /// Its nice value.
    pub nice: i32,
}

/// Every thread of process `pid` (Linux, `/proc/<pid>/task`); for tests
/// and diagnostics. Threads that end while being read are left out.
pub fn threads(pid: u32) -> io::Result<Vec<ThreadInfo>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(format!("/proc/{pid}/task"))? {
        let path = entry?.path();
        let Some(tid) = path
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.parse().ok())
        else {
            continue;
        };
        let (Ok(name), Ok(stat)) = (
            std::fs::read_to_string(path.join("comm")),
            std::fs::read_to_string(path.join("stat")),
        ) else {
            continue;
        };
        out.push(ThreadInfo {
            tid,
            name: name.trim().to_string(),
            nice: nice_of_stat(&stat)?,
        });
    }
    Ok(out)
}

/// The nice value in a `/proc/.../stat` line: the 19th field, the 17th
/// after the command (in parentheses, which may hold spaces).
fn nice_of_stat(stat: &str) -> io::Result<i32> {
    stat.rsplit_once(')')
        .and_then(|(_, rest)| rest.split_whitespace().nth(16))
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| io::Error::other("no nice field in stat"))
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn threads_started_at_a_nice_value_inherit_it_and_the_caller_keeps_its_own() {
        let before = own_nice();
        let (loader, child) = run_at_nice(7, || {
            let loader = own_nice();
            let child = std::thread::spawn(own_nice).join().unwrap();
            (loader, child)
        })
        .unwrap();
        assert_eq!((loader, child), (before.max(7), before.max(7)));
        assert_eq!(own_nice(), before);
    }

    #[test]
    fn cpu_time_grows_with_work() {
        let before = process_cpu_time();
        let mut x = 0u64;
        let started = std::time::Instant::now();
        while started.elapsed() < std::time::Duration::from_millis(30) {
            x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(7));
        }
        assert!(process_cpu_time() > before, "{x}");
    }

    #[test]
    fn zero_changes_nothing_and_stays_on_the_calling_thread() {
        let here = std::thread::current().id();
        assert_eq!(
            run_at_nice(0, || std::thread::current().id()).unwrap(),
            here
        );
    }

    /// The calling thread's nice value, as [`threads`] reads it.
    fn own_nice() -> i32 {
        // SAFETY: gettid takes nothing and returns this thread's id.
        #[allow(unsafe_code)]
        let tid = unsafe { libc::gettid() } as u32;
        threads(std::process::id())
            .unwrap()
            .into_iter()
            .find(|t| t.tid == tid)
            .unwrap()
            .nice
    }
}
