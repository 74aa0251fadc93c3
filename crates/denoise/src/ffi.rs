//! The one place tessera calls C: OIDN's C API, loaded with `libloading`. Every `unsafe` block
//! calls a function whose Rust type was written from OIDN 2's `oidn.h` prototype; the library's
//! major version is checked before anything else is called.
#![allow(unsafe_code)]

use std::ffi::{c_char, c_int, c_void, CStr, CString};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use libloading::Library;

use crate::DenoiseError;

/// The file name of OIDN 2's library on Linux.
pub const LIBRARY: &str = "libOpenImageDenoise.so.2";

/// The OIDN major version (its C ABI) this binding was written for.
const ABI: c_int = 2;
/// `OIDN_DEVICE_TYPE_CPU`: never a GPU, which the default type may pick where one is.
const DEVICE_CPU: c_int = 1;
/// `OIDN_FORMAT_FLOAT3`.
const FLOAT3: c_int = 3;

type Handle = *mut c_void;

/// OIDN's functions, as `oidn.h` declares them.
struct Fns {
    new_device: unsafe extern "C" fn(c_int) -> Handle,
    commit_device: unsafe extern "C" fn(Handle),
    release_device: unsafe extern "C" fn(Handle),
    get_device_int: unsafe extern "C" fn(Handle, *const c_char) -> c_int,
    set_device_int: unsafe extern "C" fn(Handle, *const c_char, c_int),
    get_device_error: unsafe extern "C" fn(Handle, *mut *const c_char) -> c_int,
    new_filter: unsafe extern "C" fn(Handle, *const c_char) -> Handle,
    #[allow(clippy::type_complexity)]
    set_shared_filter_image: unsafe extern "C" fn(
        Handle,
        *const c_char,
        *mut c_void,
        c_int,
        usize,
        usize,
        usize,
        usize,
        usize,
    ),
    set_filter_bool: unsafe extern "C" fn(Handle, *const c_char, bool),
    set_filter_int: unsafe extern "C" fn(Handle, *const c_char, c_int),
    commit_filter: unsafe extern "C" fn(Handle),
    execute_filter: unsafe extern "C" fn(Handle),
    release_filter: unsafe extern "C" fn(Handle),
}

/// The loaded library, for the life of the process.
pub(crate) struct Api {
    fns: Fns,
    version: c_int,
    /// Keeps the functions above mapped.
    _library: Library,
}

impl Api {
    /// The library, loaded at the first call; a failure is kept and returned to every caller.
    pub(crate) fn get() -> Result<&'static Api, DenoiseError> {
        static API: OnceLock<Result<Api, DenoiseError>> = OnceLock::new();
        API.get_or_init(load).as_ref().map_err(Clone::clone)
    }

    /// OIDN's version number (major·10000 + minor·100 + patch).
    pub(crate) fn version(&self) -> i32 {
        self.version
    }

    /// A committed CPU device with `threads` threads (`None`: OIDN's choice, every core).
    pub(crate) fn device(&self, threads: Option<u32>) -> Result<Device<'_>, DenoiseError> {
        // SAFETY: oidnNewDevice takes a device type by value and returns a handle or null.
        let handle = unsafe { (self.fns.new_device)(DEVICE_CPU) };
        if handle.is_null() {
            return Err(DenoiseError::Filter(
                "no CPU device (this CPU may lack SSE4.1)".into(),
            ));
        }
        let device = Device { api: self, handle };
        if let Some(t) = threads {
            let name = c"numThreads";
            let t = c_int::try_from(t).unwrap_or(c_int::MAX);
            // SAFETY: a live device handle and a NUL-terminated parameter name.
            unsafe { (self.fns.set_device_int)(handle, name.as_ptr(), t) };
        }
        // SAFETY: a live device handle.
        unsafe { (self.fns.commit_device)(handle) };
        device.check()?;
        Ok(device)
    }
}

/// Every place the library may be, in the order tried ([`crate`]'s documentation).
fn candidates() -> Vec<PathBuf> {
    if let Some(dir) = std::env::var_os("TESSERA_OIDN_DIR") {
        return vec![Path::new(&dir).join(LIBRARY)];
    }
    let mut places = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        for dir in exe.ancestors().skip(1).take(4) {
            let file = dir.join("oidn").join("lib").join(LIBRARY);
            if file.is_file() {
                places.push(file);
            }
        }
    }
    // Last, the system loader's own search.
    places.push(PathBuf::from(LIBRARY));
    places
}

/// Loads the first library that opens, and checks it.
fn load() -> Result<Api, DenoiseError> {
    let mut tried = Vec::new();
    for path in candidates() {
        // SAFETY: loading runs the library's initialisers; OIDN's (and TBB's) are ordinary
        // C++ static constructors.
        match unsafe { Library::new(&path) } {
            Ok(library) => return bind(library, &path),
            Err(e) => tried.push(format!("{}: {e}", path.display())),
        }
    }
    Err(DenoiseError::Missing {
        tried: tried.join("; "),
    })
}

/// The functions of a loaded library, after checking its ABI version.
fn bind(library: Library, path: &Path) -> Result<Api, DenoiseError> {
    let unusable = |why: String| DenoiseError::Unusable {
        path: path.display().to_string(),
        why,
    };
    macro_rules! sym {
        ($name:literal) => {
            // SAFETY: the symbol's type is the field's, written from oidn.h's prototype.
            *unsafe { library.get(concat!($name, "\0").as_bytes()) }.map_err(|e| {
                unusable(format!(
                    "not Open Image Denoise 2: it has no function {} ({e})",
                    $name
                ))
            })?
        };
    }
    let fns = Fns {
        new_device: sym!("oidnNewDevice"),
        commit_device: sym!("oidnCommitDevice"),
        release_device: sym!("oidnReleaseDevice"),
        get_device_int: sym!("oidnGetDeviceInt"),
        set_device_int: sym!("oidnSetDeviceInt"),
        get_device_error: sym!("oidnGetDeviceError"),
        new_filter: sym!("oidnNewFilter"),
        set_shared_filter_image: sym!("oidnSetSharedFilterImage"),
        set_filter_bool: sym!("oidnSetFilterBool"),
        set_filter_int: sym!("oidnSetFilterInt"),
        commit_filter: sym!("oidnCommitFilter"),
        execute_filter: sym!("oidnExecuteFilter"),
        release_filter: sym!("oidnReleaseFilter"),
    };
    let mut api = Api {
        fns,
        version: 0,
        _library: library,
    };
    let device = api.device(Some(1)).map_err(|e| unusable(e.to_string()))?;
    let major = device.int(c"versionMajor");
    let version = device.int(c"version");
    drop(device);
    if major != ABI {
        return Err(unusable(format!(
            "Open Image Denoise {major}.x (version {version}); tessera calls the API of version {ABI}"
        )));
    }
    api.version = version;
    Ok(api)
}

/// A committed device, released when dropped.
pub(crate) struct Device<'a> {
    api: &'a Api,
    handle: Handle,
}

impl Device<'_> {
    /// The device's first error since the last call, if any.
    fn check(&self) -> Result<(), DenoiseError> {
        let mut message: *const c_char = std::ptr::null();
        // SAFETY: a live device handle and a pointer to write the message pointer to.
        let code = unsafe { (self.api.fns.get_device_error)(self.handle, &mut message) };
        if code == 0 {
            return Ok(());
        }
        let text = if message.is_null() {
            String::new()
        } else {
            // SAFETY: OIDN returns a NUL-terminated string valid until the next call.
            unsafe { CStr::from_ptr(message) }
                .to_string_lossy()
                .into_owned()
        };
        Err(DenoiseError::Filter(format!("error {code}: {text}")))
    }

    fn int(&self, name: &CStr) -> c_int {
        // SAFETY: a live device handle and a NUL-terminated parameter name.
        unsafe { (self.api.fns.get_device_int)(self.handle, name.as_ptr()) }
    }

    /// Runs one `RT` filter of a `size` frame: `inputs` by OIDN's image names, the result into
    /// `output`, with integer and boolean parameters.
    pub(crate) fn filter(
        &self,
        size: (usize, usize),
        inputs: &[(&str, &[[f32; 3]])],
        output: &mut [[f32; 3]],
        ints: &[(&str, i32)],
        bools: &[(&str, bool)],
    ) -> Result<(), DenoiseError> {
        let n = size.0 * size.1;
        if output.len() != n || inputs.iter().any(|(_, i)| i.len() != n) {
            return Err(DenoiseError::Input(
                "an image is not the frame's size".into(),
            ));
        }
        let fns = &self.api.fns;
        // SAFETY: a live device handle and a NUL-terminated filter type.
        let handle = unsafe { (fns.new_filter)(self.handle, c"RT".as_ptr()) };
        if handle.is_null() {
            self.check()?;
            return Err(DenoiseError::Filter("no RT filter".into()));
        }
        let filter = Filter {
            api: self.api,
            handle,
        };
        let name = |s: &str| CString::new(s).map_err(|_| DenoiseError::Input(s.into()));
        let image = |n: &CStr, data: *mut c_void| {
            // SAFETY: `data` points at size.0 × size.1 packed FLOAT3 pixels, which outlive
            // the filter's execution below (they are borrowed for this whole call).
            unsafe {
                (fns.set_shared_filter_image)(
                    filter.handle,
                    n.as_ptr(),
                    data,
                    FLOAT3,
                    size.0,
                    size.1,
                    0,
                    12,
                    12 * size.0,
                )
            }
        };
        for (n, data) in inputs {
            // OIDN only reads its inputs: the pointer is `*mut` because the C API has one type.
            image(&name(n)?, data.as_ptr().cast::<c_void>().cast_mut());
        }
        image(c"output", output.as_mut_ptr().cast::<c_void>());
        for (n, v) in ints {
            // SAFETY: a live filter handle and a NUL-terminated parameter name.
            unsafe { (fns.set_filter_int)(filter.handle, name(n)?.as_ptr(), *v) };
        }
        for (n, v) in bools {
            // SAFETY: as above.
            unsafe { (fns.set_filter_bool)(filter.handle, name(n)?.as_ptr(), *v) };
        }
        // SAFETY: a live filter with every image set; execution is synchronous.
        unsafe {
            (fns.commit_filter)(filter.handle);
        }
        self.check()?;
        // SAFETY: as above.
        unsafe {
            (fns.execute_filter)(filter.handle);
        }
        self.check()
    }
}

impl Drop for Device<'_> {
    fn drop(&mut self) {
        // SAFETY: the handle is live and released once.
        unsafe { (self.api.fns.release_device)(self.handle) }
    }
}

/// A filter, released when dropped.
struct Filter<'a> {
    api: &'a Api,
    handle: Handle,
}

impl Drop for Filter<'_> {
    fn drop(&mut self) {
        // SAFETY: the handle is live and released once.
        unsafe { (self.api.fns.release_filter)(self.handle) }
    }
}
