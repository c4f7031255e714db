//! The vDSO's clocks patched to the shim's (Shadow's `patch_vdso`): each of its functions that
//! reads the time of day or time since boot starts with a jump to the shim's own, so every
//! caller — libc's internal reads (`timespec_get`, `ftime`), a runtime that looks the vDSO up
//! itself (Go's `time.Now`), a program that finds it through `/proc/self/auxv` — reads
//! simulated time for the cost of a function call, not a trapped system call.
//!
//! Patched once, from the constructor (one thread), in a followed process; a forked child
//! inherits the patched pages, an exec'd program's shim patches its own vDSO. From then on the
//! vDSO's code for these clocks is gone from this process: the shim's own reads of the host's
//! clocks are system calls ([`crate::sys::host_clocks_by_syscall`]).
//!
//! The vDSO is read as an ELF image whose every part lies inside its one loaded segment: each
//! header, section and symbol is checked against that extent before it is read, and anything
//! unexpected (another machine, no symbol table, a function too short for the jump) leaves the
//! vDSO unpatched and says so (the caller then hides it, as before: a runtime that looks it up
//! finds none and reads the clock with the system call, which traps).

use core::ffi::{c_int, c_long, c_void};

use crate::sys::{self, clockid_t, nr, time_t, timespec, timeval};
use crate::{native, time};

/// `movabs r11, imm64; jmp r11`: 13 bytes, r11 being scratch in the C calling convention.
const JUMP_LENGTH: usize = 13;

/// The vDSO's functions patched, by their names (x86_64's vDSO exports each twice: the plain
/// name and the `__vdso_` one, at one address).
const PATCHED: [(&[u8], usize); 6] = [(b"__vdso_clock_gettime", 0), (b"clock_gettime", 0), (b"__vdso_gettimeofday", 1), (b"gettimeofday", 1), (b"__vdso_time", 2), (b"time", 2)];

/// Patch the vDSO at `image` (the auxiliary vector's AT_SYSINFO_EHDR). Why not, if it was not.
pub(crate) fn patch(image: u64) -> Result<(), &'static [u8]> {
    let replacements: [usize; 3] = [clock_gettime_in_vdso as *const () as usize, gettimeofday_in_vdso as *const () as usize, time_in_vdso as *const () as usize];
    let vdso = Image::at(image).ok_or(b"the vDSO is not an ELF image this shim reads" as &[u8])?;
    let mut found: [Option<u64>; 6] = [None; 6];
    for (name, address, size) in vdso.functions() {
        if let Some(index) = PATCHED.iter().position(|(wanted, _)| *wanted == name) {
            if size < JUMP_LENGTH as u64 {
                return Err(b"a vDSO clock function is too short to patch");
            }
            found[index] = Some(address);
        }
    }
    // Each clock must be found under one of its names at least.
    for which in 0..3 {
        if !PATCHED.iter().zip(&found).any(|((_, w), at)| *w == which && at.is_some()) {
            return Err(b"the vDSO lacks a clock function");
        }
    }
    let (start, end) = vdso.text_pages();
    if native::call3(nr::MPROTECT, start as c_long, (end - start) as c_long, PROT_READ | PROT_WRITE | PROT_EXEC) != 0 {
        return Err(b"the vDSO's pages cannot be made writable");
    }
    for (&(_, which), at) in PATCHED.iter().zip(found) {
        if let Some(at) = at {
            // SAFETY: a function's first bytes inside the vDSO's text, writable now; this
            // process's one thread is here, not in the vDSO.
            unsafe { write_jump(at as *mut u8, replacements[which]) };
        }
    }
    native::call3(nr::MPROTECT, start as c_long, (end - start) as c_long, PROT_READ | PROT_EXEC);
    sys::host_clocks_by_syscall();
    Ok(())
}

const PROT_READ: c_long = 1;
const PROT_WRITE: c_long = 2;
const PROT_EXEC: c_long = 4;

/// Write `movabs r11, target; jmp r11` at `at`.
unsafe fn write_jump(at: *mut u8, target: usize) {
    let mut code = [0u8; JUMP_LENGTH];
    code[0..2].copy_from_slice(&[0x49, 0xbb]);
    code[2..10].copy_from_slice(&(target as u64).to_le_bytes());
    code[10..13].copy_from_slice(&[0x41, 0xff, 0xe3]);
    // SAFETY: the caller's writable JUMP_LENGTH bytes.
    unsafe { core::ptr::copy_nonoverlapping(code.as_ptr(), at, JUMP_LENGTH) };
}

/// The vDSO's `clock_gettime`: simulated time for the clocks the shim answers, else the
/// kernel's. A vDSO function returns the system call's raw result (0, or -errno).
///
/// Inside a libc call the shim makes for itself (`sys::OwnCalls`: a join's slice on the wall
/// clock), glibc's own clock reads are the host's, as they were before the patch: an older
/// glibc's timed join works its timeout out from the clock, against a deadline the shim gave
/// on the host's.
unsafe extern "C" fn clock_gettime_in_vdso(clock: clockid_t, ts: *mut timespec) -> c_int {
    answered(|| time::answer_clock_gettime(clock, ts)).unwrap_or_else(|| native::call2(nr::CLOCK_GETTIME, clock as c_long, ts as c_long) as c_int)
}

unsafe extern "C" fn gettimeofday_in_vdso(tv: *mut timeval, tz: *mut c_void) -> c_int {
    answered(|| time::answer_gettimeofday(tv, tz)).unwrap_or_else(|| native::call2(nr::GETTIMEOFDAY, tv as c_long, tz as c_long) as c_int)
}

unsafe extern "C" fn time_in_vdso(out: *mut time_t) -> time_t {
    answered(|| time::answer_time(out)).unwrap_or_else(|| native::call1(nr::TIME, out as c_long) as time_t)
}

/// The shim's answer, unless the shim is at work in this thread (see `clock_gettime_in_vdso`).
fn answered<T>(answer: impl FnOnce() -> Option<T>) -> Option<T> {
    if sys::in_shim() { None } else { answer() }
}

/// A mapped ELF image: its start, the extent of its one loaded segment, inside which every
/// read is checked to lie, and its dynamic section (as ld.so reads it: the section headers of
/// the vDSO lie past its loaded segment).
struct Image {
    start: u64,
    size: u64,
    /// Where the segment's addresses are in memory, less what they say.
    bias: u64,
    /// The dynamic section's offset and size.
    dynamic: (u64, u64),
}

const ELF_MAGIC: [u8; 4] = *b"\x7fELF";
const ELFCLASS64: u8 = 2;
const EM_X86_64: u16 = 62;
const PT_LOAD: u32 = 1;
const PT_DYNAMIC: u32 = 2;
const DT_NULL: u64 = 0;
const DT_HASH: u64 = 4;
const DT_STRTAB: u64 = 5;
const DT_SYMTAB: u64 = 6;
const DT_STRSZ: u64 = 10;
const STT_FUNC: u8 = 2;
const SYMBOL_SIZE: u64 = 24;
const PAGE: u64 = 4096;

impl Image {
    fn at(start: u64) -> Option<Image> {
        if start == 0 || !start.is_multiple_of(PAGE) {
            return None;
        }
        // The ELF header and the program headers lie in the image's first page.
        let first = Image { start, size: PAGE, bias: start, dynamic: (0, 0) };
        let ident: [u8; 16] = first.read(0)?;
        if ident[0..4] != ELF_MAGIC || ident[4] != ELFCLASS64 || first.read::<u16>(18)? != EM_X86_64 {
            return None;
        }
        let (phoff, phentsize, phnum) = (first.read::<u64>(32)?, u64::from(first.read::<u16>(54)?), u64::from(first.read::<u16>(56)?));
        if phentsize < 56 {
            return None;
        }
        let header = |kind: u32| {
            (0..phnum).find_map(|i| {
                let at = phoff.checked_add(i.checked_mul(phentsize)?)?;
                (first.read::<u32>(at)? == kind).then_some(at)
            })
        };
        // The image as mapped: its loaded segment, which starts at offset 0 (the ELF header).
        let load = header(PT_LOAD)?;
        let (offset, vaddr, filesz) = (first.read::<u64>(load + 8)?, first.read::<u64>(load + 16)?, first.read::<u64>(load + 32)?);
        if offset != 0 || !(64..=(64 << 20)).contains(&filesz) {
            return None;
        }
        let dynamic = header(PT_DYNAMIC)?;
        let mut image = Image { start, size: filesz, bias: start.wrapping_sub(vaddr), dynamic: (0, 0) };
        let (dynamic_at, dynamic_size) = (image.offset_of(first.read::<u64>(dynamic + 16)?)?, first.read::<u64>(dynamic + 32)?);
        (dynamic_at.checked_add(dynamic_size)? <= image.size).then_some(())?;
        image.dynamic = (dynamic_at, dynamic_size);
        Some(image)
    }

    /// A `T` at `offset` in the image, if all of it lies inside.
    fn read<T: Copy>(&self, offset: u64) -> Option<T> {
        let end = offset.checked_add(core::mem::size_of::<T>() as u64)?;
        (end <= self.size).then(|| {
            // SAFETY: inside the mapped image (checked just above).
            unsafe { ((self.start + offset) as *const T).read_unaligned() }
        })
    }

    /// The image's offset of the address `vaddr` says (the segment's addresses, less its bias).
    fn offset_of(&self, vaddr: u64) -> Option<u64> {
        let at = self.bias.wrapping_add(vaddr).checked_sub(self.start)?;
        (at < self.size).then_some(at)
    }

    /// The pages of the image (start, end).
    fn text_pages(&self) -> (u64, u64) {
        (self.start, (self.start + self.size).div_ceil(PAGE) * PAGE)
    }

    /// The image's dynamic symbols that are functions: (name, address in memory, size). Empty
    /// if its symbol table does not lie inside it.
    fn functions(&self) -> impl Iterator<Item = (&[u8], u64, u64)> + '_ {
        let (symbols, count, strings, strings_size) = self.dynamic_symbols().unwrap_or((0, 0, 0, 0));
        (0..count).filter_map(move |i| {
            let at = symbols + i * SYMBOL_SIZE;
            let (name, info, value, size) = (self.read::<u32>(at)?, self.read::<u8>(at + 4)?, self.read::<u64>(at + 8)?, self.read::<u64>(at + 16)?);
            if info & 0xf != STT_FUNC || value == 0 || u64::from(name) >= strings_size {
                return None;
            }
            let name = self.c_string(strings + u64::from(name), strings_size - u64::from(name))?;
            // The whole function inside the image.
            let offset = self.offset_of(value)?;
            (offset.checked_add(size)? <= self.size).then_some((name, self.start + offset, size))
        })
    }

    /// The dynamic symbol table from the dynamic section: (its offset, its count from the hash
    /// table's chain count, its string table's offset and size).
    fn dynamic_symbols(&self) -> Option<(u64, u64, u64, u64)> {
        let (mut symbols, mut strings, mut strings_size, mut hash) = (None, None, None, None);
        let (at, size) = self.dynamic;
        for entry in 0..size / 16 {
            let tag = self.read::<u64>(at + 16 * entry)?;
            let value = self.read::<u64>(at + 16 * entry + 8)?;
            match tag {
                DT_NULL => break,
                DT_SYMTAB => symbols = self.offset_of(value),
                DT_STRTAB => strings = self.offset_of(value),
                DT_STRSZ => strings_size = Some(value),
                DT_HASH => hash = self.offset_of(value),
                _ => {}
            }
        }
        let (symbols, strings, strings_size) = (symbols?, strings?, strings_size?);
        // The SysV hash table's second word is the number of symbols.
        let count = u64::from(self.read::<u32>(hash? + 4)?);
        if symbols.checked_add(count.checked_mul(SYMBOL_SIZE)?)? > self.size || strings.checked_add(strings_size)? > self.size {
            return None;
        }
        Some((symbols, count, strings, strings_size))
    }

    /// The NUL-terminated name at `offset`, at most `limit` bytes on.
    fn c_string(&self, offset: u64, limit: u64) -> Option<&[u8]> {
        let length = (0..limit.min(256)).find(|&i| self.read::<u8>(offset + i) == Some(0))?;
        // SAFETY: inside the image (each byte read above).
        Some(unsafe { core::slice::from_raw_parts((self.start + offset) as *const u8, length as usize) })
    }
}
