//! Serving threads pinned to CPUs, and connections steered to the thread on the CPU that
//! receives them (`--cpu-affinity`).
//!
//! With one serving thread for each CPU the process may run on (the default `--threads`),
//! thread `i` runs on the `i`-th of those CPUs only, and its listening socket carries
//! `SO_INCOMING_CPU` = that CPU: in a `SO_REUSEPORT` group Linux (6.1 and later) then gives a new
//! connection to the socket whose CPU received it (the CPU of the network card's queue; on
//! loopback, the client's), so a connection is answered on the CPU its packets arrive on, and no
//! two serving threads queue behind each other on one CPU. Unpinned, the kernel's hash spreads
//! connections over the sockets and the scheduler moves the threads: on a machine as busy as its
//! cores, requests wait out whole scheduler slices (docs/benchmarks.md, "CPU affinity").
//!
//! Both are optimisations: where the kernel refuses either (an older kernel, a sandbox), the
//! server logs it and serves unpinned.

use super::config::CpuAffinity;

/// The CPU of each serving thread, or `None` to leave them where the scheduler puts them.
/// `auto` pins only with one thread for each allowed CPU and more than one thread: fewer
/// threads pinned would leave the rest of the process (bakes, the store scan) to crowd the
/// unpinned CPUs, and one thread on one CPU gains nothing.
#[must_use]
pub fn plan(mode: CpuAffinity, threads: usize, allowed: &[usize]) -> Option<Vec<usize>> {
    match mode {
        CpuAffinity::Off => None,
        CpuAffinity::Auto => (threads > 1 && allowed.len() == threads).then(|| allowed.to_vec()),
    }
}

/// The CPUs this process may run on, ascending; empty where the system does not say (not
/// Linux) — `plan` then pins nothing.
#[must_use]
pub fn allowed_cpus() -> Vec<usize> {
    #[cfg(target_os = "linux")]
    if let Ok(set) = rustix::thread::sched_getaffinity(None) {
        return (0..rustix::thread::CpuSet::MAX_CPU).filter(|&c| set.is_set(c)).collect();
    }
    Vec::new()
}

/// Restricts the calling thread to `cpu`.
pub fn pin_current_thread(cpu: usize) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        let mut set = rustix::thread::CpuSet::new();
        set.set(cpu);
        rustix::thread::sched_setaffinity(None, &set).map_err(Into::into)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = cpu;
        Err(std::io::ErrorKind::Unsupported.into())
    }
}

/// Asks the kernel to give the listening `socket` the connections that CPU `cpu` receives.
#[cfg(unix)]
pub fn steer(socket: impl std::os::fd::AsFd, cpu: usize) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        let cpu = u32::try_from(cpu).map_err(|_| std::io::Error::from(std::io::ErrorKind::InvalidInput))?;
        rustix::net::sockopt::set_socket_incoming_cpu(socket, cpu).map_err(Into::into)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (socket, cpu);
        Err(std::io::ErrorKind::Unsupported.into())
    }
}

/// Where steering is not available at all.
#[cfg(not(unix))]
pub fn steer<T>(_socket: T, _cpu: usize) -> std::io::Result<()> {
    Err(std::io::ErrorKind::Unsupported.into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_pins_one_thread_per_allowed_cpu_only() {
        assert_eq!(plan(CpuAffinity::Auto, 2, &[0, 1]), Some(vec![0, 1]));
        // A cpuset that is not 0..n (a container on CPUs 4-7): threads take those CPUs.
        assert_eq!(plan(CpuAffinity::Auto, 4, &[4, 5, 6, 7]), Some(vec![4, 5, 6, 7]));
        // Fewer threads than CPUs (a quota, or --threads set lower), more, or one: unpinned.
        assert_eq!(plan(CpuAffinity::Auto, 2, &[0, 1, 2, 3]), None);
        assert_eq!(plan(CpuAffinity::Auto, 8, &[0, 1, 2, 3]), None);
        assert_eq!(plan(CpuAffinity::Auto, 1, &[0]), None);
        // Unknown CPUs (not Linux): unpinned.
        assert_eq!(plan(CpuAffinity::Auto, 2, &[]), None);
        assert_eq!(plan(CpuAffinity::Off, 2, &[0, 1]), None);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_pinned_thread_runs_on_its_cpu_and_a_socket_keeps_its_cpu() {
        let allowed = allowed_cpus();
        assert!(!allowed.is_empty(), "sched_getaffinity names no CPU");
        let cpu = *allowed.last().unwrap();
        let on = std::thread::spawn(move || {
            pin_current_thread(cpu).unwrap();
            let set = rustix::thread::sched_getaffinity(None).unwrap();
            (set.count(), set.is_set(cpu), rustix::thread::sched_getcpu())
        })
        .join()
        .unwrap();
        assert_eq!(on, (1, true, cpu));
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        steer(&l, cpu).unwrap();
        assert_eq!(rustix::net::sockopt::socket_incoming_cpu(&l).unwrap() as usize, cpu);
    }
}
