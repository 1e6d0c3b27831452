//! Reading a host file through semihosting (QEMU's working directory).

use cortex_m_semihosting::{nr, syscall};

/// Reads the whole file `path` (NUL-terminated) into `buf`; `None` if it
/// cannot be opened or does not fit.
pub fn read_file<'a>(path: &[u8], buf: &'a mut [u8]) -> Option<&'a [u8]> {
    if path.last() != Some(&0) {
        return None;
    }
    // SAFETY: semihosting calls with a NUL-terminated path and a buffer we own.
    unsafe {
        let fd = syscall!(OPEN, path.as_ptr(), 1usize, path.len() - 1) as isize;
        if fd < 0 {
            return None;
        }
        let len = syscall!(FLEN, fd) as usize;
        let ok = len <= buf.len() && syscall!(READ, fd, buf.as_mut_ptr(), len) == 0;
        syscall!(CLOSE, fd);
        let _ = nr::CLOSE;
        if ok {
            buf.get(..len)
        } else {
            None
        }
    }
}

/// The semihosting command line (QEMU: the kernel's path, a space and
/// `-append`'s text). `None` when there is none or it does not fit.
pub fn command_line(buf: &mut [u8]) -> Option<&[u8]> {
    let mut block = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: GET_CMDLINE writes at most `block[1]` bytes into `buf` and the
    // length it wrote into `block[1]`.
    let r = unsafe { cortex_m_semihosting::syscall1(nr::GET_CMDLINE, block.as_mut_ptr() as usize) };
    if r != 0 {
        return None;
    }
    buf.get(..block[1])
}
