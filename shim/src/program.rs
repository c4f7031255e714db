//! The program this process runs, as the kernel and the loader left it: the auxiliary vector
//! (above the environment on the initial stack) and the main executable's program headers.
//!
//! Three things come of it, all for runtimes that bypass libc:
//! - The vDSO's entry, for `vdso.rs` to patch the vDSO's clocks to the shim's: libc found the
//!   vDSO long before, and its internal clock reads (`timespec_get`, `ftime`) call it; a
//!   runtime that looks it up itself (Go's `runtime.sysargs`) calls it too, and each reads
//!   simulated time for a function call's cost. A vDSO the shim cannot patch is hidden
//!   instead: its entry becomes AT_IGNORE before the program's own start code runs, so such a
//!   runtime reads the clock with the `clock_gettime` system call, which traps.
//! - The main program's own code range, if it is a Go program or position-independent: Go
//!   makes its reads, writes, closes and waits with its own `syscall` instructions, from its
//!   text, and so does a Rust program on `rustix`'s raw backend (`polling`, `async-io`). The
//!   seccomp layer traps those calls made from there (and only there: after an exec the
//!   inherited filter must not trap a new program's loader, nor a static program's libc; a
//!   position-independent program's text lies at a random address, a Go program's at its own).
//! - The kernel's 16 random bytes for the program (AT_RANDOM) are the same in every run. libc
//!   took its stack guard and pointer guard from them before; Go seeds its hash functions and
//!   its scheduler's random choices from them (with `rdtsc`, tsc.rs), and a run must repeat.

use core::ffi::c_char;
use core::sync::atomic::{AtomicBool, AtomicU64, Ordering};

const AT_NULL: u64 = 0;
const AT_IGNORE: u64 = 1;
const AT_PHDR: u64 = 3;
const AT_PHNUM: u64 = 5;
const AT_RANDOM: u64 = 25;
const AT_SYSINFO_EHDR: u64 = 33;
/// What the kernel's 16 random bytes for the program become (see `inspect`).
const SAME_RANDOM_BYTES: &[u8; 16] = b"climbsim virtual";

const PT_LOAD: u32 = 1;
const PT_NOTE: u32 = 4;
const PT_PHDR: u32 = 6;
const PF_X: u32 = 1;
/// The Go linker's build-id note (`.note.go.buildid`): owner "Go", type 4.
const NT_GO_BUILDID: u32 = 4;

/// The executable range of the main program (start, end) whose own system calls are followed
/// (a Go program's, or a position-independent one's), or (0, 0).
static OWN_TEXT: [AtomicU64; 2] = [AtomicU64::new(0), AtomicU64::new(0)];
/// Whether the main program is a Go program.
static IS_GO: AtomicBool = AtomicBool::new(false);

/// The main program's text if its own system calls are followed there (see [`OWN_TEXT`]).
pub(crate) fn own_text() -> Option<(u64, u64)> {
    let (start, end) = (OWN_TEXT[0].load(Ordering::Relaxed), OWN_TEXT[1].load(Ordering::Relaxed));
    (end > start).then_some((start, end))
}

/// The main program's text if it is a Go program.
pub(crate) fn go_text() -> Option<(u64, u64)> {
    own_text().filter(|_| IS_GO.load(Ordering::Relaxed))
}

/// The vDSO's entry in the auxiliary vector.
pub(crate) struct VdsoEntry {
    /// Its type word, on the writable initial stack.
    kind: *mut u64,
    /// Where the vDSO's image is.
    pub(crate) image: u64,
}

impl VdsoEntry {
    /// Hide the vDSO from whoever looks it up from now on (a vDSO the shim could not patch).
    pub(crate) fn hide(&self) {
        // SAFETY: the entry's own type word, on the writable initial stack.
        unsafe { *self.kind = AT_IGNORE };
    }
}

/// Look at the program (from the constructor, with the environment pointer the loader passed):
/// note a Go program's text and, if the program is `followed`, fix the random bytes and find
/// the vDSO's entry (for `vdso.rs` to patch). (A dormant shim under an inherited filter only
/// needs to know whether its handler must run on the signal stack.)
pub(crate) fn inspect(envp: *const *const c_char, followed: bool) -> Option<VdsoEntry> {
    let auxv = auxiliary_vector(envp)?;
    let mut vdso = None;
    let (mut phdr, mut phnum) = (0u64, 0u64);
    let mut index = 0;
    loop {
        // SAFETY: the vector's pairs up to its AT_NULL, which `auxiliary_vector` checked is there.
        let (kind, value) = unsafe { (*auxv.add(2 * index), *auxv.add(2 * index + 1)) };
        match kind {
            AT_NULL => break,
            AT_PHDR => phdr = value,
            AT_PHNUM => phnum = value,
            AT_RANDOM if followed && value != 0 => {
                // SAFETY: the kernel's 16 bytes on the writable initial stack.
                unsafe { core::ptr::copy_nonoverlapping(SAME_RANDOM_BYTES.as_ptr(), value as *mut u8, 16) };
            }
            AT_SYSINFO_EHDR if followed => {
                // SAFETY: the entry's type word, within the vector.
                vdso = Some(VdsoEntry { kind: unsafe { auxv.add(2 * index) }, image: value });
            }
            _ => {}
        }
        index += 1;
    }
    if phdr != 0
        && phnum > 0
        && phnum < 256
        && let Some(((start, end), is_go)) = own_program_text(phdr, phnum as usize)
    {
        OWN_TEXT[0].store(start, Ordering::Relaxed);
        OWN_TEXT[1].store(end, Ordering::Relaxed);
        IS_GO.store(is_go, Ordering::Relaxed);
    }
    vdso
}

/// The auxiliary vector: after the environment's terminating null on the initial stack. Checked
/// against libc's own copy of two of its values, so that an environment moved by an earlier
/// constructor is never mistaken for it.
fn auxiliary_vector(envp: *const *const c_char) -> Option<*mut u64> {
    unsafe extern "C" {
        fn getauxval(kind: u64) -> u64;
    }
    if envp.is_null() {
        return None;
    }
    let mut at = envp;
    // SAFETY: the environment the loader passed is null-terminated.
    while !unsafe { *at }.is_null() {
        // SAFETY: as above, not past the terminator.
        at = unsafe { at.add(1) };
    }
    // SAFETY: one past the terminator: the vector, if this is the initial stack.
    let auxv = unsafe { at.add(1) }.cast::<u64>().cast_mut();
    // SAFETY: plain libc lookups.
    let (want_phdr, want_phnum) = unsafe { (getauxval(AT_PHDR), getauxval(AT_PHNUM)) };
    let (mut phdr_seen, mut phnum_seen) = (false, false);
    for index in 0..64 {
        // SAFETY: reading pairs until AT_NULL; the kernel's vector has a few dozen at most, and
        // a mismatch below (not the initial stack) stops at the first pair.
        let (kind, value) = unsafe { (*auxv.add(2 * index), *auxv.add(2 * index + 1)) };
        match kind {
            AT_NULL => return (phdr_seen && phnum_seen).then_some(auxv),
            AT_PHDR if value == want_phdr => phdr_seen = true,
            AT_PHNUM if value == want_phnum => phnum_seen = true,
            AT_PHDR | AT_PHNUM => return None,
            _ => {}
        }
        if index == 0 && kind > 64 {
            return None;
        }
    }
    None
}

/// struct Elf64_Phdr.
#[repr(C)]
#[derive(Clone, Copy)]
struct ProgramHeader {
    kind: u32,
    flags: u32,
    offset: u64,
    vaddr: u64,
    paddr: u64,
    filesz: u64,
    memsz: u64,
    align: u64,
}

/// If the main program is a Go program (it carries Go's build-id note) or position-independent
/// (loaded at a bias): its executable segment's range in memory, and whether it is Go.
fn own_program_text(phdr: u64, count: usize) -> Option<((u64, u64), bool)> {
    // SAFETY: the loader's program headers of the main program, `count` of them, mapped.
    let headers = unsafe { core::slice::from_raw_parts(phdr as *const ProgramHeader, count) };
    // A position-independent program is loaded at a bias: where its headers are, less where
    // they say they are.
    let bias = headers.iter().find(|h| h.kind == PT_PHDR).map_or(0, |h| phdr.wrapping_sub(h.vaddr));
    let is_go = headers.iter().filter(|h| h.kind == PT_NOTE).any(|h| has_go_note(bias.wrapping_add(h.vaddr), h.memsz));
    if !is_go && bias == 0 {
        return None;
    }
    Some((executable_segment(headers, bias)?, is_go))
}

/// The range in memory of the executable segment among `headers`, loaded at `bias`.
fn executable_segment(headers: &[ProgramHeader], bias: u64) -> Option<(u64, u64)> {
    let text = headers.iter().find(|h| h.kind == PT_LOAD && h.flags & PF_X != 0)?;
    let start = bias.wrapping_add(text.vaddr);
    Some((start, start.checked_add(text.memsz)?))
}

unsafe extern "C" {
    /// The shim's own ELF header, where the linker put it: the start of its first loaded
    /// segment (`ld` and `lld` define it in every object whose header is loaded).
    static __ehdr_start: u8;
}

/// The range in memory of the shim's own executable segment, from its own ELF and program
/// headers (no look at /proc: every followed process asks as it starts).
pub(crate) fn shim_text() -> Option<(u64, u64)> {
    // Offsets in struct Elf64_Ehdr of e_phoff (u64) and e_phnum (u16).
    const E_PHOFF: u64 = 32;
    const E_PHNUM: u64 = 56;
    let header = &raw const __ehdr_start as u64;
    // SAFETY: the shim's own ELF header, mapped with its first segment.
    let (phoff, count) = unsafe { (((header + E_PHOFF) as *const u64).read_unaligned(), ((header + E_PHNUM) as *const u16).read_unaligned()) };
    // SAFETY: its program headers, `count` of them, mapped with the header they follow.
    let headers = unsafe { core::slice::from_raw_parts((header + phoff) as *const ProgramHeader, usize::from(count)) };
    // A shared object is loaded at a bias: where its header is, less where its first segment
    // (the one that holds the header, at file offset 0) says it is.
    let first = headers.iter().find(|h| h.kind == PT_LOAD && h.offset == 0)?;
    executable_segment(headers, header.wrapping_sub(first.vaddr))
}

/// Whether the notes at `address` (`size` bytes, mapped: notes lie in a loaded segment)
/// include Go's build id.
fn has_go_note(address: u64, size: u64) -> bool {
    let align4 = |n: u64| n.div_ceil(4) * 4;
    let mut at = 0u64;
    while at + 12 <= size {
        // SAFETY: within the note segment (checked above and below).
        let word = |offset: u64| unsafe { ((address + at + offset) as *const u32).read_unaligned() };
        let (name_size, desc_size, kind) = (u64::from(word(0)), u64::from(word(4)), word(8));
        let name_end = 12 + align4(name_size);
        if at + name_end > size {
            return false;
        }
        // Go writes its owner as "Go\0\0" (4 bytes).
        if kind == NT_GO_BUILDID && (3..=4).contains(&name_size) {
            // SAFETY: the note's name, within the segment.
            let name = unsafe { core::slice::from_raw_parts((address + at + 12) as *const u8, 3) };
            if name == b"Go\0" {
                return true;
            }
        }
        at += name_end + align4(desc_size);
    }
    false
}
