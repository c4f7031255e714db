//! The shim's own way into the kernel: one `syscall` instruction on a page at a fixed address.
//!
//! The seccomp filter (`seccomp.rs`) lets through only the system calls made from this page;
//! every other call of the families climbsim follows traps into the shim. The address is fixed,
//! not wherever the loader put the shim, because the filter outlives an exec: the new program's
//! shim maps its page at the same place before it makes a call of its own, and the filter the
//! first program installed still lets it through.
//!
//! Before the page exists (or where the filter is not used) calls go through libc's `syscall`,
//! which is equally native then.

use core::ffi::{c_int, c_long, c_void};
use core::sync::atomic::{AtomicBool, Ordering};

/// Where the page goes: high in the lower half of the address space, far from where Linux puts
/// programs, libraries, heaps and stacks ("lmb" in ASCII, for "climb").
pub const PAGE_ADDRESS: usize = 0x6c6d_6200_0000;
pub const PAGE_BYTES: usize = 4096;

/// `long call(long nr, long a, long b, long c, long d, long e, long f)` in the System V ABI,
/// turned into the kernel's calling convention (x86_64 machine code, hand-assembled):
///
/// ```text
/// 48 89 f8        mov rax, rdi
/// 48 89 f7        mov rdi, rsi
/// 48 89 d6        mov rsi, rdx
/// 48 89 ca        mov rdx, rcx
/// 4d 89 c2        mov r10, r8
/// 4d 89 c8        mov r8, r9
/// 4c 8b 4c 24 08  mov r9, [rsp + 8]
/// 0f 05           syscall
/// c3              ret
/// ```
#[cfg(target_arch = "x86_64")]
const CODE: [u8; 26] = [0x48, 0x89, 0xf8, 0x48, 0x89, 0xf7, 0x48, 0x89, 0xd6, 0x48, 0x89, 0xca, 0x4d, 0x89, 0xc2, 0x4d, 0x89, 0xc8, 0x4c, 0x8b, 0x4c, 0x24, 0x08, 0x0f, 0x05, 0xc3];

/// Where on the page the signal restorer starts: `mov eax, 15 (rt_sigreturn); syscall`, for a
/// handler installed with the kernel's own sigaction (libc's would trap under an inherited
/// filter before the handler is there).
#[cfg(target_arch = "x86_64")]
pub const RESTORER_OFFSET: usize = 32;
#[cfg(target_arch = "x86_64")]
const RESTORER: [u8; 7] = [0xb8, 0x0f, 0x00, 0x00, 0x00, 0x0f, 0x05];

/// Where on the page a trapped thread creation (clone with CLONE_THREAD) is made again, from
/// the page, once the trap handler has returned: the new thread cannot come back through the
/// handler (its stack is another), so both threads go back to the program from here.
///
/// ```text
/// 0f 05        syscall          (clone, on the registers the handler left)
/// 48 85 c0     test rax, rax
/// 74 08        je child
/// 59           pop rcx          (the parent: the return address and its stack pointer,
/// 41 5b        pop r11           which the handler put where the signal's siginfo was)
/// 4c 89 dc     mov rsp, r11
/// ff e1        jmp rcx
/// c3           child: ret       (the return address the handler put on the new stack)
/// ```
///
/// rcx and r11 are what `syscall` clobbers anyway.
#[cfg(target_arch = "x86_64")]
pub const CLONE_OFFSET: usize = 48;
#[cfg(target_arch = "x86_64")]
const CLONE: [u8; 16] = [0x0f, 0x05, 0x48, 0x85, 0xc0, 0x74, 0x08, 0x59, 0x41, 0x5b, 0x4c, 0x89, 0xdc, 0xff, 0xe1, 0xc3];

/// Set once the page holds the code (in this process image).
static READY: AtomicBool = AtomicBool::new(false);

unsafe extern "C" {
    fn __errno_location() -> *mut c_int;
    fn syscall(number: c_long, ...) -> c_long;
    fn mmap(addr: *mut c_void, len: usize, prot: c_int, flags: c_int, fd: c_int, offset: i64) -> *mut c_void;
    fn mprotect(addr: *mut c_void, len: usize, prot: c_int) -> c_int;
    fn munmap(addr: *mut c_void, len: usize) -> c_int;
}

/// Map the page and write the code into it; whether it is there. Called once per process image,
/// from the constructor, before the filter is installed (or, after an exec, before anything
/// else the shim does: the inherited filter lets the shim's calls through only from here).
#[cfg(target_arch = "x86_64")]
pub fn map_page() -> bool {
    if READY.load(Ordering::Acquire) {
        return true;
    }
    const PROT_READ: c_int = 1;
    const PROT_WRITE: c_int = 2;
    const PROT_EXEC: c_int = 4;
    const MAP_PRIVATE: c_int = 2;
    const MAP_ANONYMOUS: c_int = 0x20;
    const MAP_FIXED_NOREPLACE: c_int = 0x100000;
    let wanted = PAGE_ADDRESS as *mut c_void;
    // mmap, mprotect and munmap are not among the calls the filter traps (the loader makes them
    // before any shim can handle a trap), so libc's wrappers are fine here.
    // SAFETY: an anonymous mapping at an address nothing else uses (NOREPLACE checks).
    let page = unsafe { mmap(wanted, PAGE_BYTES, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_FIXED_NOREPLACE, -1, 0) };
    if page != wanted {
        if page as isize != -1 {
            // An old kernel that took NOREPLACE as a hint and put it elsewhere.
            // SAFETY: unmapping what was just mapped.
            unsafe { munmap(page, PAGE_BYTES) };
        }
        return false;
    }
    // SAFETY: the page is ours, writable and PAGE_BYTES long; int3 fills the rest.
    unsafe {
        core::ptr::write_bytes(page.cast::<u8>(), 0xcc, PAGE_BYTES);
        core::ptr::copy_nonoverlapping(CODE.as_ptr(), page.cast::<u8>(), CODE.len());
        core::ptr::copy_nonoverlapping(RESTORER.as_ptr(), page.cast::<u8>().add(RESTORER_OFFSET), RESTORER.len());
        core::ptr::copy_nonoverlapping(CLONE.as_ptr(), page.cast::<u8>().add(CLONE_OFFSET), CLONE.len());
        if mprotect(page, PAGE_BYTES, PROT_READ | PROT_EXEC) != 0 {
            munmap(page, PAGE_BYTES);
            return false;
        }
    }
    READY.store(true, Ordering::Release);
    true
}

#[cfg(not(target_arch = "x86_64"))]
pub fn map_page() -> bool {
    false
}

type Entry = unsafe extern "C" fn(c_long, c_long, c_long, c_long, c_long, c_long, c_long) -> c_long;

/// A system call made natively: from the page once it exists, through libc before. Returns what
/// the kernel returns (a negative errno on failure); errno is not touched.
pub fn call6(number: c_long, a: c_long, b: c_long, c: c_long, d: c_long, e: c_long, f: c_long) -> c_long {
    if READY.load(Ordering::Acquire) {
        // SAFETY: the page holds CODE, a function of this signature.
        let entry = unsafe { core::mem::transmute::<usize, Entry>(PAGE_ADDRESS) };
        // SAFETY: the caller's arguments are the system call's; the kernel checks them.
        return unsafe { entry(number, a, b, c, d, e, f) };
    }
    let saved = errno();
    // SAFETY: as above, through libc, which returns -1 and sets errno instead.
    let result = unsafe { syscall(number, a, b, c, d, e, f) };
    let result = if result == -1 { -c_long::from(errno()) } else { result };
    set_errno(saved);
    result
}

pub fn call0(number: c_long) -> c_long {
    call6(number, 0, 0, 0, 0, 0, 0)
}

pub fn call1(number: c_long, a: c_long) -> c_long {
    call6(number, a, 0, 0, 0, 0, 0)
}

pub fn call2(number: c_long, a: c_long, b: c_long) -> c_long {
    call6(number, a, b, 0, 0, 0, 0)
}

pub fn call3(number: c_long, a: c_long, b: c_long, c: c_long) -> c_long {
    call6(number, a, b, c, 0, 0, 0)
}

pub fn call4(number: c_long, a: c_long, b: c_long, c: c_long, d: c_long) -> c_long {
    call6(number, a, b, c, d, 0, 0)
}

/// This thread's errno (glibc's, valid for the calling thread).
pub fn errno() -> c_int {
    // SAFETY: glibc's errno location is valid for the calling thread.
    unsafe { *__errno_location() }
}

pub fn set_errno(value: c_int) {
    // SAFETY: as above.
    unsafe { *__errno_location() = value };
}
