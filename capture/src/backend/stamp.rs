//! Host clock reads that stamp frames: `CLOCK_MONOTONIC` (the clock V4L2 stamps buffers
//! with) and the wall clock.

/// CLOCK_MONOTONIC now, nanoseconds (the clock V4L2 stamps buffers with).
pub fn monotonic_now_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .map(|t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
        .unwrap_or(0)
}

/// CLOCK_REALTIME now, nanoseconds since the Unix epoch.
pub fn wall_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}
