//! A list as long as one call needs: the timerfds and sensor connections of one wait. The first
//! few live inline (a wait rarely has more), the rest in pages mapped for the list and given back
//! when it goes. (The shim has no allocator: it runs inside signal handlers and before libc's
//! own allocator is safe to call.)

use core::mem::size_of;

/// Items kept without mapping pages.
const INLINE: usize = 16;

pub(crate) struct GrowingList<T: Copy + Default> {
    inline: [T; INLINE],
    len: usize,
    /// Pages holding every item once there are more than [`INLINE`] (null before).
    mapped: *mut T,
    /// Items the mapped pages hold.
    capacity: usize,
}

impl<T: Copy + Default> Default for GrowingList<T> {
    fn default() -> Self {
        GrowingList { inline: [T::default(); INLINE], len: 0, mapped: core::ptr::null_mut(), capacity: 0 }
    }
}

impl<T: Copy + Default> GrowingList<T> {
    /// Add `item`; false if no memory could be mapped for it (the list is as it was).
    #[must_use]
    pub(crate) fn push(&mut self, item: T) -> bool {
        if self.mapped.is_null() && self.len < INLINE {
            self.inline[self.len] = item;
            self.len += 1;
            return true;
        }
        if (self.mapped.is_null() || self.len == self.capacity) && !self.grow() {
            return false;
        }
        // SAFETY: `len` < `capacity`, items the mapped pages hold.
        unsafe { self.mapped.add(self.len).write(item) };
        self.len += 1;
        true
    }

    /// Move the items to pages twice as large (the first time: four times the inline room).
    fn grow(&mut self) -> bool {
        let capacity = (self.capacity * 2).max(INLINE * 4);
        let Some(pages) = crate::sys::fresh_pages(capacity * size_of::<T>()) else { return false };
        let pages = pages.cast::<T>();
        // SAFETY: both hold `len` items; the new pages are the list's own.
        unsafe { core::ptr::copy_nonoverlapping(self.as_slice().as_ptr(), pages, self.len) };
        self.release();
        (self.mapped, self.capacity) = (pages, capacity);
        true
    }

    pub(crate) fn as_slice(&self) -> &[T] {
        if self.mapped.is_null() {
            &self.inline[..self.len]
        } else {
            // SAFETY: the mapped pages hold `len` items written by `push`.
            unsafe { core::slice::from_raw_parts(self.mapped, self.len) }
        }
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn release(&mut self) {
        if !self.mapped.is_null() {
            crate::sys::release_pages(self.mapped.cast(), self.capacity * size_of::<T>());
            self.mapped = core::ptr::null_mut();
        }
    }
}

impl<T: Copy + Default> Drop for GrowingList<T> {
    fn drop(&mut self) {
        self.release();
    }
}
