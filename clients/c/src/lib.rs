//! `libincise_c`: the incise client for C. A driver includes `protocol/include/incise.h`, links
//! this library, and calls:
//!
//! ```c
//! InciseClient *c = incise_connect("iceoryx2", "demo_organ", 0, "tcp/127.0.0.1:7447");
//! if (!c) fprintf(stderr, "%s\n", incise_last_error());
//! incise_send_pose(c, &pose);                 /* 0: sent */
//! InciseForce f;
//! if (incise_recv_force(c, &f, 1000) == 1) …  /* 1: a force, 0: none within 1000 µs */
//! incise_disconnect(c);
//! ```
//!
//! Errors are returned as codes; `incise_last_error` gives the last one's message on the calling
//! thread. Nothing here panics across the boundary: a panic is caught and reported as an error.

#![allow(unsafe_code, reason = "the C ABI: raw pointers from C, checked before use")]

use incise_protocol::keys::Keys;
use incise_protocol::raw::{RawToolForce, RawToolPose};
use incise_transport::{Client, TransportKind};
use std::cell::RefCell;
use std::ffi::{CStr, CString, c_char};
use std::time::Duration;

/// A connection of one tool, opaque to C.
pub struct InciseClient(Client);

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn fail(message: impl Into<String>) {
    let text = message.into().replace('\0', " ");
    LAST_ERROR.with(|e| *e.borrow_mut() = CString::new(text).unwrap_or_default());
}

/// A C string argument as UTF-8, or the error recorded.
///
/// # Safety
/// `s` is null or points to a NUL-terminated string that lives for the call.
unsafe fn text<'a>(s: *const c_char, what: &str) -> Option<&'a str> {
    if s.is_null() {
        fail(format!("{what} is NULL"));
        return None;
    }
    // SAFETY: non-null, and the caller passes a NUL-terminated string valid for the call.
    let text = unsafe { CStr::from_ptr(s) }.to_str().ok();
    if text.is_none() {
        fail(format!("{what} is not UTF-8"));
    }
    text
}

/// Connects tool `tool` of scene `scene` over `transport` (`"zenoh"` or `"iceoryx2"`); zenoh
/// connects to `endpoint` (`"tcp/HOST:PORT"`). Returns NULL on failure (see
/// [`incise_last_error`]).
///
/// # Safety
/// The strings are NUL-terminated and live for the call (`endpoint` may be NULL for iceoryx2).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn incise_connect(
    transport: *const c_char,
    scene: *const c_char,
    tool: u32,
    endpoint: *const c_char,
) -> *mut InciseClient {
    // SAFETY: forwarded from this function's own contract.
    let (Some(kind), Some(scene)) =
        (unsafe { text(transport, "transport") }, unsafe { text(scene, "scene") })
    else {
        return std::ptr::null_mut();
    };
    let endpoint = if endpoint.is_null() {
        ""
    } else {
        // SAFETY: as above.
        match unsafe { text(endpoint, "endpoint") } {
            Some(e) => e,
            None => return std::ptr::null_mut(),
        }
    };
    let connected = std::panic::catch_unwind(|| -> Result<Client, String> {
        let kind: TransportKind = kind.parse()?;
        let keys = Keys::new(scene).map_err(|e| e.to_string())?;
        Client::connect(kind, &keys, tool, endpoint).map_err(|e| e.to_string())
    });
    match connected {
        Ok(Ok(client)) => Box::into_raw(Box::new(InciseClient(client))),
        Ok(Err(e)) => {
            fail(e);
            std::ptr::null_mut()
        }
        Err(_) => {
            fail("incise_connect panicked");
            std::ptr::null_mut()
        }
    }
}

/// Sends a pose. Returns 0 when sent, -1 on failure.
///
/// # Safety
/// `client` comes from [`incise_connect`] and was not disconnected; `pose` points to an
/// `IncisePose`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn incise_send_pose(
    client: *const InciseClient,
    pose: *const RawToolPose,
) -> i32 {
    if client.is_null() || pose.is_null() {
        fail("incise_send_pose: NULL argument");
        return -1;
    }
    // SAFETY: both non-null; the caller guarantees they point to live objects of these types.
    let (client, pose) = unsafe { (&*client, &*pose) };
    match client.0.send_pose(pose) {
        Ok(()) => 0,
        Err(e) => {
            fail(e.to_string());
            -1
        }
    }
}

/// Waits up to `timeout_us` for the next force. Returns 1 with `*out` set, 0 when none came,
/// -1 on failure.
///
/// # Safety
/// `client` comes from [`incise_connect`]; `out` points to writable `InciseForce` storage.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn incise_recv_force(
    client: *const InciseClient,
    out: *mut RawToolForce,
    timeout_us: u32,
) -> i32 {
    if client.is_null() || out.is_null() {
        fail("incise_recv_force: NULL argument");
        return -1;
    }
    // SAFETY: non-null, and the caller guarantees a live client.
    let client = unsafe { &*client };
    match client.0.recv_force(Duration::from_micros(u64::from(timeout_us))) {
        Some(force) => {
            // SAFETY: non-null, writable storage for one `InciseForce` (caller's contract).
            unsafe { out.write(force) };
            1
        }
        None => 0,
    }
}

/// Closes the connection and frees it. NULL is ignored.
///
/// # Safety
/// `client` comes from [`incise_connect`] and is not used afterwards.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn incise_disconnect(client: *mut InciseClient) {
    if !client.is_null() {
        // SAFETY: made by `Box::into_raw` in `incise_connect`, and given back once.
        drop(unsafe { Box::from_raw(client) });
    }
}

/// The last error's message on this thread (empty when there was none). Valid until the next
/// call that fails on this thread.
#[unsafe(no_mangle)]
pub extern "C" fn incise_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}
