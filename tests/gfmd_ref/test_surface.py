"""Surface generator: amplitude, spectrum slope, reproducibility (conventions: docs page gfmd)."""
import numpy as np
import pytest

from gfmd_ref import self_affine_surface, spectral_rms_slope


def _radial_psd(h, length):
    """Shell-averaged |h~(q)|^2 with h~ = ifft2(h) (the package's Fourier convention)."""
    n = h.shape[0]
    ht = np.fft.ifft2(h)
    k = 2 * np.pi * np.fft.fftfreq(n, d=length / n)
    q = np.sqrt(k[:, None] ** 2 + k[None, :] ** 2)
    return q.ravel(), (np.abs(ht) ** 2).ravel()


def test_rms_slope_is_as_asked():
    n, L = 128, 128.0
    h = self_affine_surface(n, length=L, hurst=0.3, q_min=2 * np.pi / L,
                            q_max=2 * np.pi / 8, rms_slope=0.031, seed=3)
    # Independent oracle: spectral gradient field in real space, <|grad h|^2>.
    # The amplitude is set from the realised modes, so only round-off remains (1e-12).
    k = 2 * np.pi * np.fft.fftfreq(n, d=L / n)
    H = np.fft.fft2(h)
    gx = np.fft.ifft2(1j * k[:, None] * H).real
    gy = np.fft.ifft2(1j * k[None, :] * H).real
    assert np.sqrt(np.mean(gx**2 + gy**2)) == pytest.approx(0.031, rel=1e-12)
    assert spectral_rms_slope(h, L) == pytest.approx(0.031, rel=1e-12)


def test_h_rms_real_zero_mean_odd_n():
    n, L = 45, 3.0
    h = self_affine_surface(n, length=L, hurst=0.8, q_min=2 * np.pi / L,
                            q_max=2 * np.pi * 10 / L, h_rms=0.25, seed=11)
    assert h.shape == (n, n) and h.dtype == np.float64 and np.isrealobj(h)
    # zero mean and h_rms to round-off (the amplitude is fixed from the realisation)
    assert abs(h.mean()) < 1e-14
    assert np.sqrt(np.mean(h**2)) == pytest.approx(0.25, rel=1e-12)


@pytest.mark.parametrize("rayleigh, tol", [(False, 0.03), (True, 0.1)])
def test_spectrum_slope(rayleigh, tol):
    """Log-log fit of |h~(q)|^2 over the band gives -2(1+H).

    Tolerances: with fixed amplitudes (rayleigh=False) every mode is exactly on the
    power law, so only the fit over a discrete lattice remains (0.03). With
    Rayleigh amplitudes each |h~|^2 is exponential-distributed (log has sd ~1.3); a
    fit over ~2e4 modes has a slope standard error ~0.02, 0.1 is 5 sigma.
    """
    n, L, H = 256, 256.0, 0.3
    qmin, qmax = 2 * np.pi / L * 2, 2 * np.pi / 4
    h = self_affine_surface(n, length=L, hurst=H, q_min=qmin, q_max=qmax,
                            rms_slope=0.05, seed=5, rayleigh=rayleigh)
    q, c = _radial_psd(h, L)
    band = (q >= qmin) & (q <= qmax)
    slope = np.polyfit(np.log(q[band]), np.log(c[band]), 1)[0]
    assert slope == pytest.approx(-2 * (1 + H), abs=tol)
    # nothing outside the band (round-off only)
    assert np.max(c[~band]) < 1e-20 * np.max(c[band])


def test_roll_off_is_flat():
    n, L = 128, 128.0
    q1 = 2 * np.pi / L
    h = self_affine_surface(n, length=L, hurst=0.5, q_min=q1, q_max=20 * q1, q_roll=5 * q1,
                            h_rms=1.0, seed=2, rayleigh=False)
    q, c = _radial_psd(h, L)
    low = (q >= q1) & (q < 5 * q1 * (1 - 1e-9))
    # fixed amplitudes: flat part is constant to round-off
    assert np.ptp(np.log(c[low])) < 1e-8


def test_seed_reproducibility():
    kw = dict(length=16.0, hurst=0.3, q_min=0.4, q_max=3.0, rms_slope=0.1)
    a = self_affine_surface(16, seed=42, **kw)
    b = self_affine_surface(16, seed=42, **kw)
    c = self_affine_surface(16, seed=43, **kw)
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)
    # golden values (numpy default_rng(42) + pocketfft); platforms may differ by FFT
    # round-off only, hence rtol 1e-10
    np.testing.assert_allclose(a[0, :3], [2.70948999e-03, 2.41875839e-05, 3.59566465e-02],
                               rtol=1e-8)
    assert a[5, 7] == pytest.approx(-0.049208920034479714, rel=1e-10)


@pytest.mark.parametrize(
    "kw, name",
    [
        (dict(rms_slope=0.1, h_rms=0.1), "rms_slope"),
        (dict(), "rms_slope"),
        (dict(rms_slope=0.1, q_max=0.1), "q_max"),
        (dict(rms_slope=0.1, hurst=1.5), "hurst"),
        (dict(rms_slope=-0.1), "rms_slope"),
        (dict(rms_slope=0.1, length=0.0), "length"),
        (dict(rms_slope=0.1, q_roll=10.0), "q_roll"),
        # wrong types: a message naming the parameter, not a raw numpy error
        (dict(rms_slope=0.1, hurst="0.3"), "hurst"),
        (dict(rms_slope=0.1, hurst=float("nan")), "hurst"),
        (dict(rms_slope=0.1, hurst=None), "hurst"),
        (dict(rms_slope=0.1, seed=1.0), "seed"),
        (dict(rms_slope=0.1, seed=-1), "seed"),
        (dict(rms_slope=0.1, seed="1"), "seed"),
        (dict(rms_slope=0.1, seed=True), "seed"),
        (dict(rms_slope=0.1, length="16"), "length"),
        (dict(rms_slope=0.1, q_min=None), "q_min"),
        (dict(rms_slope=0.1, rayleigh="yes"), "rayleigh"),
    ],
)
def test_bad_input(kw, name):
    base = dict(length=16.0, hurst=0.3, q_min=0.4, q_max=3.0, seed=1)
    base.update(kw)
    with pytest.raises(ValueError, match=name):
        self_affine_surface(16, **base)


@pytest.mark.parametrize("n", [0, 1, 2.0, "16", None])
def test_bad_grid_size(n):
    with pytest.raises(ValueError, match="n must be"):
        self_affine_surface(n, length=16.0, hurst=0.3, q_min=0.4, q_max=3.0, rms_slope=0.1, seed=1)


@pytest.mark.parametrize("length", [1e-200, 1.0, 1e200])
def test_any_length_scale_without_overflow(length):
    """The band is built on the integer lattice: same surface in units of length, any scale.

    Oracle: the surface is scale-free apart from its amplitude, so h(length)/length is
    the same array for every length (rms slope fixed), to FFT round-off.
    """
    import warnings

    kw = dict(hurst=0.3, rms_slope=0.05, seed=7)
    ref = self_affine_surface(32, length=1.0, q_min=2 * np.pi, q_max=16 * np.pi, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow/underflow warnings on the way
        h = self_affine_surface(32, length=length, q_min=2 * np.pi / length, q_max=16 * np.pi / length, **kw)
    assert np.all(np.isfinite(h))
    np.testing.assert_allclose(h / length, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
