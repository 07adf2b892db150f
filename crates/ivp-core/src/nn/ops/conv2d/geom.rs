//! What the convolution and its narrow kernels (`narrow.rs`) share: the shapes of one
//! convolution, the shared output pointer of a parallel loop, and the floating-point mode the
//! kernels run in. A sibling of `narrow`, so that `narrow` need not import its parent, which calls it.

/// Shapes of one convolution.
#[derive(Clone, Copy, Debug)]
pub(super) struct Geom {
    pub(super) batch: usize,
    pub(super) cin: usize,
    pub(super) h: usize,
    pub(super) w: usize,
    pub(super) cout: usize,
    pub(super) k: usize,
    pub(super) stride: usize,
    pub(super) pad: usize,
    pub(super) ho: usize,
    pub(super) wo: usize,
}

impl Geom {
    pub(super) fn new(
        (batch, cin, h, w): (usize, usize, usize, usize),
        cout: usize,
        k: usize,
        stride: usize,
        pad: usize,
    ) -> Self {
        let ho = (h + 2 * pad - k) / stride + 1;
        let wo = (w + 2 * pad - k) / stride + 1;
        Self { batch, cin, h, w, cout, k, stride, pad, ho, wo }
    }

    /// Rows of the im2col matrix, the depth of the forward product: Cin k k.
    pub(super) fn taps(&self) -> usize {
        self.cin * self.k * self.k
    }

    /// Output pixels of one image.
    pub(super) fn pixels(&self) -> usize {
        self.ho * self.wo
    }

    /// Input image `b` of `x` (Cin, H, W).
    pub(super) fn image<'a>(&self, x: &'a [f32], b: usize) -> &'a [f32] {
        let len = self.cin * self.h * self.w;
        &x[b * len..][..len]
    }
}

/// Runs `f` with subnormal floats flushed to zero on this thread (see the module documentation).
pub(super) fn flushing_denormals<R>(f: impl FnOnce() -> R) -> R {
    // SAFETY: the floating-point mode changes for this thread only and is restored when `f`
    // returns (or unwinds). The code under it is the kernels' loops and gemm's, which LLVM cannot
    // constant-fold across the change, and a flushed subnormal is a value of 0 to them.
    unsafe { no_denormals::no_denormals(f) }
}

/// A raw output pointer that tiles of one parallel loop share; each writes its own part.
#[derive(Clone, Copy)]
pub(super) struct SharedMut(pub(super) *mut f32);
// SAFETY: only used for writes to disjoint parts, as argued at each use.
unsafe impl Send for SharedMut {}
unsafe impl Sync for SharedMut {}

impl SharedMut {
    /// A method rather than field access, so that closures capture the Sync wrapper.
    pub(super) fn at(self, offset: usize) -> *mut f32 {
        self.0.wrapping_add(offset)
    }
}
