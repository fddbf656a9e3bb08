"""The corpus cases of issue 21 (make_corpus.py calls add_issue21_cases): power chains and exp
towers in every position, a template's undefined name (an input's default reading a state),
a scene value of the wrong shape, size checks on a scene's model, --tols bounds, a Radau run
that diverges, ordinary names (P, x0, C...), compilers that run but fail, C name collisions,
linearize on models that are not finite, and a table that links to itself."""
from __future__ import annotations


def _chain(x: str, n: int = 150) -> str:
    for _ in range(n):
        x = f"({x})**2"
    return x


def _tower(x: str, n: int = 100) -> str:
    for _ in range(n):
        x = f"exp({x})"
    return x


BADCC = ("#!/bin/sh\nif [ \"$1\" = --version ]; then echo badcc 1.0; exit 0; fi\n"
         "echo 'badcc: error: cannot compile anything' >&2\nexit 1\n")

COLLIDE = ("bgc: 1\nname: collide\nparameters: {main: 2.0, m_main: 200.0, bgcu_main: 4.0}\n"
           "elements:\n  force: {type: Se, effort: \"1.0\"}\n"
           '  mass: {type: I, inertia: "main"}\n  spring: {type: C, stiffness: "m_main"}\n'
           '  damper: {type: R, resistance: "bgcu_main"}\n  v: {type: "1"}\n'
           "bonds:\n  - [force, v]\n  - [v, mass]\n  - [v, spring]\n  - [v, damper]\n"
           'outputs: {x: "q(spring)"}\n')

BALL = ("bgc: 1\nname: ball\nparameters: {m: 1.0, k: 1.0e6, g: 9.81}\nelements:\n"
        '  grav: {type: Se, effort: "-m*g"}\n  mass: {type: I, inertia: "m"}\n'
        '  floor: {type: C, effort: "k*max(-q(floor), 0)", initial: 0.01}\n  v: {type: "1"}\n'
        "bonds:\n  - [grav, v]\n  - [v, mass]\n  - [v, floor]\n"
        'outputs: {height: "q(floor)"}\n')


def add_issue21_cases(C, base_rel: str, MSD, SCENE, dq) -> None:
    _expressions(C, MSD, SCENE, dq)
    _semantic(C, MSD, dq)
    _files_and_options(C, base_rel)
    _compilers(C, base_rel)
    _linearize_and_runs(C, MSD)


def _expressions(C, MSD, SCENE, dq) -> None:
    """1 and 2: power chains, overflowing powers, exp towers: located, never OverflowError."""
    chain = _chain("k")
    where = {
        "law": ("e_damper", lambda x: f"  damper: {{type: R, resistance: {dq(x)}}}"),
        "derived": ("p_F0", lambda x: f"  F0: {dq(x)}"),
        "input": ("i_F", lambda x: f"  F: {{default: {dq(x)}}}"),
        "state": ("s_W", lambda x: f"  W: {{initial: 0, derivative: {dq(x)}}}"),
        "output": ("o_vel", lambda x: f"  velocity: {dq('f(mass)*' + x)}"),
    }
    msg = "chain of powers|exponent|is .* but|dimensionless"
    for pos, (key, fmt) in where.items():
        C.model_case("expr", f"pow_chain_{pos}", MSD, expect="error", key=key, message=msg,
                     line=("p_F0", "i_F") if pos == "derived" else None,
                     note="((k**2)**2)... 150 deep: sympy merges it to k**(2**150)",
                     **{key: fmt(chain)})
    for pos in ("law", "derived", "input", "state"):
        key, fmt = where[pos]
        C.model_case("expr", f"pow_overflow_{pos}", MSD, expect="error", message="finite|inf|is .* but|dimensionless",
                     line=("e_mass", "e_damper", "p_F0", "s_W", "bgc", "i_F"),
                     note="k**900 overflows a double: inf and the located diagnosis, never "
                          "OverflowError", **{key: fmt("k**900")})
    C.model_case("expr", "pow_overflow_output", MSD, expect="ok",
                 o_vel=f"  velocity: {dq('f(mass)*k**900')}",
                 note="an output that overflows: the module returns inf, never raises")
    for name, law in (("exp_tower_q", _tower("q(spring)")), ("exp_tower_f", _tower("f(damper)"))):
        key = "e_spring" if "q(" in law else "e_damper"
        el = "spring: {type: C" if key == "e_spring" else "damper: {type: R"
        C.model_case("expr", name, MSD, expect="error", message="finite|inf|nan|is .* but|dimensionless",
                     line=("e_mass", key), **{key: f"  {el}, effort: {dq(law)}}}"},
                     note="exp(exp(...)) 100 deep over a state: bounded, located")
    C.scene_case("expr", "pow_chain_scene_input", expect="error", key="inputs", simulate=True,
                 inputs=f"inputs: {{F: {dq(_chain('F0'))}}}", message=msg,
                 note="the power chain in a scene's input")


def _semantic(C, MSD, dq) -> None:
    """3, 4 and 8: the template's undefined names, shapes, ordinary names."""
    C.model_case("semantic", "input_default_reads_state", MSD, expect="error", key="i_F",
                 i_F='  F: {default: "W"}', message="state|parameters|is .* but|dimensionless",
                 note="was UndefinedError 's_W' in the template")
    C.model_case("semantic", "input_default_reads_input", MSD, expect="error", key="i_F",
                 i_F=['  F: {default: "2*G"}', '  G: "F0"'], message="input|parameters",
                 note="was UndefinedError 'u_G' in the template")
    C.scene_case("semantic", "scene_param_shape", expect="error", key="parameters",
                 parameters="parameters: {m: [[1.0, 2.0], [3.0, 4.0]]}",
                 message="2x2.*scalar|shape", note="a matrix for a scalar parameter")
    C.scene_case("semantic", "scene_param_vector", expect="error", key="parameters",
                 parameters="parameters: {m: [1.0, 2.0, 3.0]}", message="3x1.*scalar|shape")
    for nm in ("P", "x0", "C", "D", "J", "dx", "rhs", "N_STATES"):
        twin_text, _ = MSD.make([f"# the clean twin of semantic/ordinary_{nm}"],
                                p_k="  kk: {value: 200.0, unit: N/m}",
                                e_spring='  spring: {type: C, stiffness: "kk"}',
                                o_vel=['  velocity: "f(mass)"', '  spring_force: "kk*q(spring)"'])
        twin = C.write(f"semantic/ordinary_{nm}.twin.yaml", twin_text)
        C.model_case("semantic", f"ordinary_{nm}", MSD, expect="ok", twin="twin.yaml",
                     extra_files={"twin.yaml": twin},
                     p_k=f"  {nm}: {{value: 200.0, unit: N/m}}",
                     e_spring=f'  spring: {{type: C, stiffness: "{nm}"}}',
                     o_vel=['  velocity: "f(mass)"', f'  spring_force: "{nm}*q(spring)"'],
                     note="an ordinary name (a pressure P, an initial volume x0): accepted, "
                          "the same rhs as the clean twin")


def _files_and_options(C, base_rel) -> None:
    """5, 6 and 9: a scene's model that is a 10 GB sparse file, --tols, a table linking to
    itself."""
    C.scene_case("resources", "scene_model_sparse_10g", expect="error", key="model",
                 model="model: big.yaml", argv=["simulate", "scene.yaml", "-q"], out_files=[],
                 setup=[{"kind": "sparse", "name": "big.yaml", "size": 10 << 30}],
                 message="size|large|limit|bytes")
    C.cases[-1]["line"] = [1, C.cases[-1]["line"]]
    scene = C.write("cli/scene_accuracy.yaml", "bgc_scene: 1\nmodel: model.yaml\n"
                                               "duration: 0.5\n")
    files = {"model.yaml": base_rel, "scene.yaml": scene}
    for name, tols in (("tols_1e-300", "1e-3:1e-300"), ("tols_list_1e-15", "1e-3,1e-15")):
        C.add("cli", f"accuracy_{name}", argv=["accuracy", "scene.yaml", "--tols", tols, "-q"],
              expect="error", files=files, message="tols.*1e-14", located=False, check=None,
              note="tolerances below what double precision resolves")
    text = ("bgc: 1\nname: tab\nparameters: {m: 1.0}\ninputs:\n  F: {table: self.csv}\n"
            'elements:\n  s: {type: Se, effort: "F"}\n  mass: {type: I, inertia: "m"}\n'
            "bonds:\n  - [s, mass]\n")
    rel = C.write("resources/table_self_link.yaml", "# fuzz case resources/table_self_link: "
                                                    "expect error\n" + text)
    C.add("resources", "table_self_link", argv=["compile", "model.yaml", "-o", "out.py", "-q"],
          expect="error", files={"model.yaml": rel}, line=6, message="link|loop",
          setup=[{"kind": "symlink", "name": "self.csv", "target": "self.csv"}],
          check=["check", "model.yaml"], note="a table that is a symlink to itself")


def _compilers(C, base_rel) -> None:
    """9 and 10: compilers that run but fail, CC with an unbalanced quote, C names that
    collide after renaming, a relative output folder."""
    bad = [{"kind": "repeat", "name": "badcc", "head": BADCC, "item": "", "count": 0},
           {"kind": "chmod", "name": "badcc", "mode": "755"}]
    mf = {"model.yaml": base_rel}
    for name, env, setup in (("cc_fails", {"CC": "./badcc"}, bad),
                             ("cc_unbalanced_quote", {"CC": 'cc "-O2'}, [])):
        C.add("cli", f"{name}_compile_c", argv=["compile", "model.yaml", "--target", "c", "-o",
                                                "out/", "--no-cache", "-q"],
              expect="error", files=mf, setup=setup, env=env, located=False, check=None,
              message="compiler|CC")
        scene = C.write("cli/scene_c.yaml", "bgc_scene: 1\nmodel: model.yaml\nduration: 0.2\n"
                                            "solver: {backend: c}\n")
        C.add("cli", f"{name}_simulate_falls_back",
              argv=["simulate", "scene.yaml", "--out", "r.npz", "--no-cache", "-q"],
              expect="ok", files={**mf, "scene.yaml": scene}, setup=setup, env=env,
              outputs=["r.npz"], check=None, note="simulate falls back to numpy")
    rel = C.write("cli/collide.yaml", COLLIDE)
    C.add("cli", "c_names_collide", argv=["compile", "model.yaml", "--target", "c", "-o",
                                          "out/", "--no-cache", "-q"],
          expect="ok", files={"model.yaml": rel}, outputs=["out/"], check=None,
          note="main is renamed in C: it may not become another model name (m_main)")
    C.add("cli", "c_relative_nested_folder",
          argv=["compile", "model.yaml", "--target", "c", "-o", "sub/msd_c/", "--no-cache",
                "-q"], expect="ok", files=mf, outputs=["sub/"], check=None,
          note="the README's relative -o folder (the compiler runs in another folder)")


def _linearize_and_runs(C, MSD) -> None:
    """7 and 9: linearize on models that are not finite; Radau on a diverging run."""
    cases = {"zero_mass": ("p_m", "  m: {value: 0.0, unit: kg}", ("p_m", "e_mass")),
             "k_over_q": ("e_spring", '  spring: {type: C, effort: "k/q(spring)"}',
                          ("e_mass", "e_spring")),
             "sqrt_negative": ("p_c", "  c: -4.0", ("p_c", "e_mass", "e_damper"))}
    for name, (key, line, lines) in cases.items():
        changes = {key: line}
        if name == "sqrt_negative":
            changes["e_damper"] = '  damper: {type: R, resistance: "sqrt(c)"}'
        text, where = MSD.make(C.header(f"cli/linearize_{name}", "error"), **changes)
        rel = C.write(f"cli/linearize_{name}.yaml", text)
        C.add("cli", f"linearize_{name}", argv=["linearize", "model.yaml", "-q"],
              expect="error", files={"model.yaml": rel}, check=None,
              line=[where[k] for k in lines], message="finite|equilibrium|linearise|is .* but|dimensionless")
    rel = C.write("runtime/ball.yaml", "# a floor with the wrong sign: the ball falls through "
                                       "and accelerates\n" + BALL)
    srel = C.write("runtime/ball_radau.yaml", "# fuzz case runtime/ball_radau: expect error\n"
                   "bgc_scene: 1\nmodel: model.yaml\nduration: 1\nsolver: {method: Radau, rtol: 0.01, atol: 0.01}\n")
    C.add("runtime", "ball_radau", argv=["simulate", "scene.yaml", "--out", "r.npz", "-q"],
          expect="error", files={"scene.yaml": srel, "model.yaml": rel}, outputs=["r.npz"],
          message="floor|mass|finite", exit=(1, 2), located=False, check=None,
          note="Radau's Newton system overflows: the located diagnosis, exit 1")
