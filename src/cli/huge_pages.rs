//! Transparent huge pages for the heap (issue 25).
//!
//! A tick visits every vehicle's components, readings, mailbox and a stretch of its lane's path:
//! tens of megabytes at 10,000 vehicles, read in an order the 4 KiB pages' translation cache
//! cannot hold. With the heap on 2 MiB pages (and [`SETTINGS`]) the same work took 11 to 13 %
//! less time (`bench --vehicles 10000 --duration 10`, 7 alternating turns, paired: 0.890 on one
//! thread, 0.867 on two; Intel Xeon, 2 cores). At `--vehicles 100000 --duration 2` the best
//! runs are faster (0.86 -> 0.76 s) but the median moves with how fresh the pages the kernel
//! hands over in the first ticks are (paired 0.91, 0.97 and 1.12 in three sets of turns).
//!
//! Most Linux kernels give huge pages only to memory that asks for them (`madvise`, the
//! `[madvise]` mode of `/sys/kernel/mm/transparent_hugepage/enabled`), and glibc's malloc asks
//! only when the tunable `glibc.malloc.hugetlb=1` is set when the process starts: the dynamic
//! loader reads `GLIBC_TUNABLES` before any of our code runs (glibc manual, "Memory Allocation
//! Tunables"). So `smlworld`, started without it where the kernel is in that mode, starts itself
//! again at once with it added ([`restart_with_huge_pages`]): the same program, arguments, name
//! and process id, the rest of the environment unchanged. `SMLWORLD_HUGE_PAGES=0` turns this off;
//! a `GLIBC_TUNABLES` that names the tunable already is left as the user set it.
//!
//! A custom global allocator that advised its own large blocks was tried first: it reached
//! 2 MiB of huge pages where glibc reaches 24 MiB, because glibc grows its heaps in small steps
//! and touches each step before an allocator above it could advise it.

use std::ffi::{OsStr, OsString};

/// The environment variable that turns the restart off (`0`); the restarted process finds it
/// set (to `1`), which also stops a second restart.
pub const SWITCH: &str = "SMLWORLD_HUGE_PAGES";
/// glibc's tunable: malloc advises the kernel to back its heaps with transparent huge pages.
const TUNABLE: &str = "glibc.malloc.hugetlb";
/// What the restart adds to `GLIBC_TUNABLES` (before the user's own, which win where they name
/// the same tunable): huge pages, and a heap that keeps what it once touched. Each page the
/// kernel hands over is a 2 MiB one to clear (and on a virtual machine, often to back), so a
/// heap that gives memory back and takes it again (glibc trims above 128 KiB free at the top,
/// and maps large blocks apart, unmapping them when freed) pays that again and again: the
/// 100,000-vehicle run took 13 to 17 % longer with huge pages alone. Growing the heap 64 MiB
/// at a time, trimming only above 1 GiB free, and taking blocks below 32 MiB from the heap
/// made it 9 % faster instead in the same minutes (peak memory 285 MB against 263 MB).
const SETTINGS: &str = "glibc.malloc.hugetlb=1:glibc.malloc.top_pad=67108864:glibc.malloc.trim_threshold=1073741824:glibc.malloc.mmap_threshold=33554432";
/// Where Linux says when it gives transparent huge pages.
#[cfg_attr(not(all(target_os = "linux", target_env = "gnu")), allow(dead_code))]
const THP_MODE: &str = "/sys/kernel/mm/transparent_hugepage/enabled";

/// The `GLIBC_TUNABLES` to restart with, or `None` to go on as we are: `switch` is
/// [`SWITCH`]'s value, `tunables` the `GLIBC_TUNABLES` we were started with, `thp_mode` what
/// [`THP_MODE`] holds (`None`: no such file, no transparent huge pages).
pub fn tunables_for_huge_pages(
    switch: Option<&OsStr>,
    tunables: Option<&OsStr>,
    thp_mode: Option<&str>,
) -> Option<OsString> {
    // Turned off, or this is the restarted process.
    if switch.is_some() {
        return None;
    }
    // `[always]`: every large area has huge pages already; `[never]`: none can.
    if !thp_mode?.contains("[madvise]") {
        return None;
    }
    match tunables.filter(|t| !t.is_empty()) {
        // The user chose (on or off).
        Some(t) if t.to_string_lossy().contains(TUNABLE) => None,
        Some(t) => {
            let mut joined = OsString::from(SETTINGS);
            joined.push(":");
            joined.push(t);
            Some(joined)
        }
        None => Some(SETTINGS.into()),
    }
}

/// Start this program again, at once, with glibc's malloc on transparent huge pages, where
/// [`tunables_for_huge_pages`] says it helps (Linux with glibc). Call it first thing in `main`,
/// before any thread exists. Returns only when it did not restart (not needed, turned off, or
/// the restart failed: then the run goes on without huge pages).
pub fn restart_with_huge_pages() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use std::os::unix::process::CommandExt;
        let mode = std::fs::read_to_string(THP_MODE).ok();
        let switch = std::env::var_os(SWITCH);
        let tunables = std::env::var_os("GLIBC_TUNABLES");
        let Some(tunables) = tunables_for_huge_pages(switch.as_deref(), tunables.as_deref(), mode.as_deref()) else {
            return;
        };
        let mut args = std::env::args_os();
        let arg0 = args.next().unwrap_or_else(|| OsString::from("smlworld"));
        // The program's own path, not `/proc/self/exe`, which would name the process `exe` in
        // `ps` and `top`; that link only when the file is gone (rebuilt while starting).
        let program = std::env::current_exe()
            .ok()
            .filter(|p| p.is_file())
            .unwrap_or_else(|| std::path::PathBuf::from("/proc/self/exe"));
        // `exec` replaces this process; it returns only with the reason it could not.
        let _failed = std::process::Command::new(program)
            .arg0(arg0)
            .args(args)
            .env("GLIBC_TUNABLES", tunables)
            .env(SWITCH, "1")
            .exec();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn os(s: &str) -> Option<&OsStr> {
        Some(OsStr::new(s))
    }

    #[test]
    fn restarts_only_in_the_madvise_mode_without_a_choice_made() {
        let madvise = Some("always [madvise] never\n");
        let ours = "glibc.malloc.hugetlb=1:glibc.malloc.top_pad=67108864:glibc.malloc.trim_threshold=1073741824:glibc.malloc.mmap_threshold=33554432";
        assert_eq!(tunables_for_huge_pages(None, None, madvise), Some(ours.into()));
        assert_eq!(tunables_for_huge_pages(None, os(""), madvise), Some(ours.into()));
        // The user's other tunables are kept, last, so that theirs win (glibc reads them in order).
        assert_eq!(
            tunables_for_huge_pages(None, os("glibc.malloc.top_pad=0"), madvise),
            Some(format!("{ours}:glibc.malloc.top_pad=0").into())
        );
        // The user's own choice, either way, stands.
        assert_eq!(tunables_for_huge_pages(None, os("glibc.malloc.hugetlb=0"), madvise), None);
        assert_eq!(tunables_for_huge_pages(None, os("a=1:glibc.malloc.hugetlb=2"), madvise), None);
        // Turned off, or already restarted.
        assert_eq!(tunables_for_huge_pages(os("0"), None, madvise), None);
        assert_eq!(tunables_for_huge_pages(os("1"), None, madvise), None);
        // Kernels that give huge pages to every large area, to none, or have none.
        assert_eq!(tunables_for_huge_pages(None, None, Some("[always] madvise never")), None);
        assert_eq!(tunables_for_huge_pages(None, None, Some("always madvise [never]")), None);
        assert_eq!(tunables_for_huge_pages(None, None, None), None);
    }
}
