"""linearize(): analytic A, B, C, D against hand-written matrices, closed-form modes and
transfer functions, and central finite differences of rhs and outputs."""
from __future__ import annotations

import numpy as np
import pytest

QC = dict(m_s=250.0, m_u=35.0, k_s=16000.0, c_s=1000.0, k_t=160000.0, g=9.81)


def _qc_A(m_s, m_u, k_s, c_s, k_t, **_):
    """The quarter-car's A by hand, states (p_s, p_u, q_s = z_s - z_u, q_t = z_u):
    p_s' = -k_s q_s - c_s (p_s/m_s - p_u/m_u) - m_s g, p_u' = k_s q_s + c_s (...) - k_t q_t
    - m_u g, q_s' = p_s/m_s - p_u/m_u, q_t' = p_u/m_u."""
    return np.array([
        [-c_s / m_s, c_s / m_u, -k_s, 0.0],
        [c_s / m_s, -c_s / m_u, k_s, -k_t],
        [1 / m_s, -1 / m_u, 0.0, 0.0],
        [0.0, 1 / m_u, 0.0, 0.0]])


def _fd(f, x, h):
    """Central differences of f (vector -> vector) at x, column by column."""
    cols = []
    for j in range(len(x)):
        e = np.zeros(len(x))
        e[j] = h[j]
        cols.append((f(x + e) - f(x - e)) / (2 * h[j]))
    return np.stack(cols, axis=1)


def test_quarter_car_A_is_the_hand_written_matrix(gen):
    m = gen("quarter_car")
    assert m.STATE_NAMES == ("sprung.p", "unsprung.p", "spring.q", "tyre.q")
    x = np.array([3.0, -1.0, -0.1, 0.02])
    A, B, C, D = m.linearize(0.0, x)
    np.testing.assert_allclose(A, _qc_A(**QC), rtol=1e-13, atol=1e-12)
    # the road enters through the tyre: d(p_u')/d(z_r) = k_t
    np.testing.assert_allclose(B, [[0.0], [QC["k_t"]], [0.0], [0.0]])
    assert m.INPUT_LABELS == ("zr",)


def test_quarter_car_undamped_modes_are_the_two_mass_closed_form(gen):
    m = gen("quarter_car")
    p = dict(QC, c_s=0.0)
    A = m.linearize(0.0, m.X0, p={"c_s": 0.0})[0]
    lam = np.linalg.eigvals(A)
    assert np.max(np.abs(lam.real)) < 1e-9 * np.max(np.abs(lam))
    w = np.sort(np.abs(lam.imag))[::2]  # each frequency once
    # m_s m_u w^4 - (m_s (k_s + k_t) + m_u k_s) w^2 + k_s k_t = 0
    a = p["m_s"] * p["m_u"]
    b = -(p["m_s"] * (p["k_s"] + p["k_t"]) + p["m_u"] * p["k_s"])
    c = p["k_s"] * p["k_t"]
    w2 = np.sort([(-b - np.sqrt(b * b - 4 * a * c)) / (2 * a), (-b + np.sqrt(b * b - 4 * a * c))
                  / (2 * a)])
    np.testing.assert_allclose(w, np.sqrt(w2), rtol=1e-10)
    assert 1.1 < w[0] / (2 * np.pi) < 1.3 and 11 < w[1] / (2 * np.pi) < 11.4  # Hz


def test_quarter_car_damped_eigenvalues(gen):
    m = gen("quarter_car")
    A = m.linearize(0.0, m.X0)[0]
    got = np.sort_complex(np.linalg.eigvals(A))
    want = np.sort_complex(np.linalg.eigvals(_qc_A(**QC)))
    np.testing.assert_allclose(got, want, rtol=1e-10)


@pytest.mark.parametrize("name", ["quarter_car", "dc_motor", "pendulum", "van_der_pol",
                                  "two_tanks", "motor_thermal"])
def test_A_B_C_D_equal_central_differences(gen, name):
    m = gen(name)
    rng = np.random.default_rng(3)
    x = np.asarray(m.X0, dtype=float) * (1 + 0.1 * rng.standard_normal(m.N_STATES)) \
        + 0.05 * rng.standard_normal(m.N_STATES)
    if name == "two_tanks":  # levels stay positive (square roots)
        x = np.abs(x) + 0.5
    t = 0.3
    A, B, C, D = m.linearize(t, x)
    hx = 1e-6 * (1 + np.abs(x))
    np.testing.assert_allclose(A, _fd(lambda z: m.rhs(t, z), x, hx), rtol=1e-5,
                               atol=1e-6 * (1 + np.max(np.abs(A))))

    def y(z, u=None):
        return np.concatenate([np.ravel(v) for v in m.outputs(t, z, None, u).values()])

    np.testing.assert_allclose(C, _fd(y, x, hx), rtol=1e-5, atol=1e-6 * (1 + np.max(np.abs(C))))
    assert C.shape == (len(m.OUTPUT_LABELS), m.N_STATES)
    # inputs: hold each at its default value plus a perturbation
    assert B.shape == (m.N_STATES, len(m.INPUT_LABELS)) and D.shape[1] == len(m.INPUT_LABELS)
    if not m.INPUT_LABELS:
        return
    flat = np.array([float(np.asarray(v)) for v in m._inputs(t, m._params(None)[0], None)])

    def signals(uf):
        out, k = {}, 0
        for name_ in m.INPUT_NAMES:
            n_ = sum(1 for lbl in m.INPUT_LABELS if lbl == name_ or lbl.startswith(name_ + "["))
            val = uf[k:k + n_]
            out[name_] = (lambda tt, v=val.copy(): v[0] if len(v) == 1 else v)
            k += n_
        return out

    hu = 1e-6 * (1 + np.abs(flat))
    Bfd = _fd(lambda uf: m.rhs(t, x, None, signals(uf)), flat, hu)
    Dfd = _fd(lambda uf: y(x, signals(uf)), flat, hu)
    np.testing.assert_allclose(B, Bfd, rtol=1e-5, atol=1e-6 * (1 + np.max(np.abs(B))))
    np.testing.assert_allclose(D, Dfd, rtol=1e-5, atol=1e-6 * (1 + np.max(np.abs(D))))


def test_no_inputs_gives_empty_B_and_D(gen):
    m = gen("pendulum")
    A, B, C, D = m.linearize(0.0, m.X0)
    assert m.INPUT_LABELS == () and B.shape == (2, 0) and D.shape == (len(m.OUTPUT_LABELS), 0)


def test_linearize_is_batched_like_rhs(gen):
    m = gen("quarter_car")
    ks = np.array([1.0e4, 1.6e4, 2.5e4])
    A, B, C, D = m.linearize(0.0, m.X0, p={"k_s": ks})
    assert A.shape == (4, 4, 3) and B.shape == (4, 1, 3) and C.shape[2] == 3
    for i, k in enumerate(ks):
        np.testing.assert_allclose(A[..., i], _qc_A(**dict(QC, k_s=k)), rtol=1e-13, atol=1e-12)


def _motor_tf(s, R_a=2.0, L_a=5e-3, K=0.05, J_r=1e-4, b=1e-5):
    """Speed over voltage of the DC motor: K / ((L s + R)(J s + b) + K^2)."""
    return K / ((L_a * s + R_a) * (J_r * s + b) + K * K)


def test_dc_motor_voltage_to_speed_is_the_closed_form(gen):
    from bgc.linear import frequency_response

    m = gen("dc_motor")
    lin = m.linearize(0.0, m.X0)
    f = np.array([0.1, 2.0, 30.0, 200.0, 3000.0])  # Hz
    i_in, i_out = m.INPUT_LABELS.index("V"), m.OUTPUT_LABELS.index("speed")
    H = frequency_response(*lin, i_in, i_out, 2 * np.pi * f)
    want = _motor_tf(2j * np.pi * f)
    np.testing.assert_allclose(20 * np.log10(np.abs(H)), 20 * np.log10(np.abs(want)),
                               atol=1e-9)
    np.testing.assert_allclose(np.degrees(np.angle(H)), np.degrees(np.angle(want)), atol=1e-9)
    # DC gain: w_ss / V = K / (K^2 + R b)
    assert abs(np.abs(frequency_response(*lin, i_in, i_out, np.array([0.0]))[0])
               - 0.05 / (0.05 ** 2 + 2.0 * 1e-5)) < 1e-9


def test_control_statespace_when_installed(gen):
    control = pytest.importorskip("control")
    from bgc.linear import to_statespace

    m = gen("dc_motor")
    ss = to_statespace(m, *m.linearize(0.0, m.X0))
    w = 2 * np.pi * 30.0
    i, o = m.INPUT_LABELS.index("V"), m.OUTPUT_LABELS.index("speed")
    H = control.evalfr(ss[o, i], 1j * w)
    assert abs(H - _motor_tf(1j * w)) < 1e-9 * abs(_motor_tf(1j * w))


def test_cli_linearize_writes_modes_matrices_and_bode(bgc_cli, tmp_path):
    r = bgc_cli("linearize", "models/quarter_car.yaml", "--at", "equilibrium",
                "--out", str(tmp_path), "--bode", "zr:body_height", "-q")
    assert r.returncode == 0, r.stderr
    lam = np.linalg.eigvals(_qc_A(**QC))
    fn = np.sort(np.abs(lam)) / (2 * np.pi)
    for hz in fn[::2]:
        assert f"{hz:.4g}" in r.stdout
    assert "tyre.q" in r.stdout and "damping" in r.stdout
    z = np.load(tmp_path / "quarter_car_linear.npz")
    np.testing.assert_allclose(z["A"], _qc_A(**QC), rtol=1e-12, atol=1e-12)
    assert list(z["states"]) == ["sprung.p", "unsprung.p", "spring.q", "tyre.q"]
    png = tmp_path / "bode_zr_body_height.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bad = bgc_cli("linearize", "models/quarter_car.yaml", "--bode", "zr:nope", "-q")
    assert bad.returncode == 2 and "nope" in bad.stderr and "Traceback" not in bad.stderr


def test_cli_linearize_a_scene_at_a_time(bgc_cli, tmp_path):
    """A scene (its signals compiled in) at t = 0: the initial state; the DC motor's A has the
    hand-derived eigenvalues of [[-R/L, -K/J], [K/L, -b/J]] (states L i, J w)."""
    r = bgc_cli("linearize", "models/scenes/dc_motor_load_step.yaml", "--at", "0",
                "--out", str(tmp_path), "-q")
    assert r.returncode == 0, r.stderr
    z = np.load(next(tmp_path.glob("*_linear.npz")))
    R, L, K, J, b = 2.0, 5e-3, 0.05, 1e-4, 1e-5
    A = np.array([[-R / L, -K / J], [K / L, -b / J]])
    np.testing.assert_allclose(np.sort(z["eigenvalues"].real), np.sort(np.linalg.eigvals(A).real),
                               rtol=1e-10)
    assert "t = 0 s" in r.stdout


def test_api_linearize_gives_modes_and_statespace():
    from pathlib import Path

    import bgc

    lin = bgc.linearize(Path(__file__).resolve().parents[1] / "models" / "quarter_car.yaml")
    want = np.linalg.eigvals(_qc_A(**QC))
    got = sorted(m.wn for m in lin.modes)
    np.testing.assert_allclose(got, np.sort(np.abs(want))[::2], rtol=1e-10)
    assert lin.inputs == ("zr",) and lin.states[2] == "spring.q"
    if lin.statespace is not None:
        np.testing.assert_allclose(lin.statespace.A, lin.A)


def test_bode_plot_shows_dollar_signs_as_written(tmp_path):
    """Labels and units come from the model: a '$' is text, not mathtext (a malformed
    formula such as '$\\frac' made matplotlib fail while saving)."""
    from bgc.linear import bode_plot

    A = np.array([[-1.0]])
    B = np.array([[1.0]])
    C = np.array([[1.0]])
    D = np.array([[0.0]])
    path = tmp_path / "bode.png"
    bode_plot(path, (A, B, C, D), 0, 0, "u$\\frac", "y$", in_unit="$\\frac{", out_unit="m$")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_output_jacobian_of_angles_and_of_what_only_outputs_read():
    """C and D where an output is an angle atan2(y, x) (differentiated by its chain rule in
    symengine) and where an output reads an assignment the rhs never needs (the source's
    flow: C's forward sweep goes on from the state Jacobian's past what that one visited),
    against central differences of the outputs; and the same matrices as C swept anew."""
    import dataclasses
    from pathlib import Path

    from bgc.backends.load import load_module
    from bgc.format.parse import parse_text
    from bgc.lower import ir
    from bgc.run.driver import compile_model

    text = (Path(__file__).resolve().parents[1] / "models" / "msd.yaml").read_text()
    text = text.replace("outputs:\n", 'outputs:\n  angle: {expr: "atan2(k*q(spring), '
                        'c*f(force) + F)", unit: rad}\n  power_in: {expr: "e(force)*f(force)", '
                        'unit: W}\n')
    c = compile_model(parse_text(text, "msd_angle.yaml"))
    m = load_module(c.source, "msd_angle")
    assert m.OUTPUT_NAMES[:2] == ("angle", "power_in")
    t, x = 0.3, np.array([0.7, -0.02])
    A, B, C, D = m.linearize(t, x)

    def y(z, u=None):
        return np.concatenate([np.ravel(v) for v in m.outputs(t, z, None, u).values()])

    h = 1e-6 * (1 + np.abs(x))
    np.testing.assert_allclose(C, _fd(y, x, h), rtol=1e-6, atol=1e-9)
    assert abs(C[1, 0]) > 1.0  # d(F v)/dp = F/m: the source's flow, read by no derivative
    Dfd = _fd(lambda uf: y(x, {"F": lambda tt, v=uf[0]: v}), np.array([10.0]), np.array([1e-5]))
    np.testing.assert_allclose(D, Dfd, rtol=1e-6, atol=1e-9)
    # the same C and D as a sweep that does not go on from the Jacobian's (a sliced scene's)
    again = ir.lower_linear(dataclasses.replace(c.equations, jac_tangents=None))
    low = dataclasses.replace(c.lowered, linear=again)
    m2 = load_module(_render(c, low), "msd_angle_anew")
    for a, b in zip(m.output_jacobian(t, x), m2.output_jacobian(t, x)):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-15)


def _render(c, low) -> str:
    from bgc.backends.numpy.printer import render

    return render(c.equations, source="msd_angle.yaml", source_hash=c.model.source_hash,
                  lowered=low)
