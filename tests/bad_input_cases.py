"""The bad-input corpus (issue 15): one row a case, run by tests/test_bad_input.py.

A case is ``(id, argv, files, field)``: ``argv`` is the ``mrm`` command line, in which
``{robot}``, ``{config}``, ``{line}`` stand for files the case writes from ``files`` (their
TOML text; a name ending in ``_csv``, such as ``{traj_csv}``, is written as ``traj.csv``) and
``{out}`` for a result folder or file that must not appear; ``field`` is what the one
line on stderr must name. Every case must be refused before anything is simulated.
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MRM3 = (ROOT / "models" / "robots" / "mrm3.toml").read_text()
TABLE2 = (ROOT / "configs" / "table2.toml").read_text()
LINE = (ROOT / "examples" / "line.toml").read_text()

_TYPE = '\n[module_types.X]\nlike = "I"\n'
_TWO = 'name = "t"\n[[modules]]\ntype = "X"\n[[modules]]\ntype = "I"\ntwist_deg = 90.0\n'


def _robot_with(type_lines: str) -> str:
    return _TWO + _TYPE + type_lines + "\n"


def _config_with(section: str, key: str, value: str) -> str:
    """table2.toml with ``key`` of ``[section]`` set to ``value`` (added if absent)."""
    lines = TABLE2.splitlines()
    out, inside, done = [], False, False
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("["):
            if inside and not done:
                out.append(f"{key} = {value}")
                done = True
            inside = stripped.split("#")[0].strip() == f"[{section}]"
        if inside and stripped.split("=")[0].strip() == key:
            out.append(f"{key} = {value}")
            done = True
            continue
        out.append(line)
    if not done:
        if not inside:
            out.append(f"[{section}]")
        out.append(f"{key} = {value}")
    return "\n".join(out) + "\n"


def _line_with(old: str, new: str) -> str:
    assert old in LINE, old
    return LINE.replace(old, new, 1)


CASES: list[tuple[str, list[str], dict[str, str], str]] = []


def case(id_, argv, field, **files):
    CASES.append((id_, argv, files, field))


# --- robot descriptions, through `mrm robot show` --------------------------------------
ROBOT_FIELDS = {
    "length_a": ["200", "-0.1", "0.0", "nan", "inf", '"0.2"', "1e300", "true", "[0.2]"],
    "length_b": ["100", "-1", "nan", '"x"', "1e9"],
    "max_speed": ["1e300", "-1", "0", "nan", "21"],
    "peak_torque": ["-1", "0", "nan", '"11"', "1e9"],
    "continuous_torque": ["-1", "nan", '"4"'],
    "gear_ratio": ["0", "-100", "1.5", '"100"', "true", "80"],
    "encoder_lines": ["0", "-1", "2.5", "1e22", '"2000"'],
    "joint_limit_deg": ["0", "-10", "nan", "400"],
    "joint_limit": ["0", "4"],
    "actuator": ['"FHA-99"', "3", '""'],
    "link_a": ["[1e-12, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1e-6, 1e-6, 1e-6]",
               "[100, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1]",
               "[1, 0, 0, 0, 0, 0, 0, 0, 0, 0, -1, 1, 1]",
               "[1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 5]",
               "[1, 2, 3]", '"heavy"',
               # m·rx² = 0.5 disagrees with m = 1, m·rx = 0.1 (0.01)
               "[1, 0.1, 0, 0, 0.5, 0, 0, 0, 0, 0, 0.01, 0.01, 0.01]"],
}
for key, values in ROBOT_FIELDS.items():
    for i, value in enumerate(values):
        field = f"module_types.X.{key}"
        case(f"robot-{key}-{i}", ["robot", "show", "{robot}"], field,
             robot=_robot_with(f"{key} = {value}"))
case("robot-nm-links", ["robot", "show", "{robot}"], "module_types.X.length_a",
     robot=_robot_with("length_a = 1e-9\nlength_b = 1e-9"))

MODULE_ENTRY = {
    "twist_deg": ["1e300", "nan", '"90"', "[90]"],
    "type": ['"III"', '["I"]', "{ name = \"I\" }", "1"],
    "spring": ['{ torque = 8.0 }'],
    "colour": ['"red"'],
}
for key, values in MODULE_ENTRY.items():
    for i, value in enumerate(values):
        type_line = "" if key == "type" else 'type = "I"'
        doc = f'name = "t"\n[[modules]]\n{type_line}\n{key} = {value}\n'
        case(f"robot-module-{key}-{i}", ["robot", "show", "{robot}"], f"modules[0].{key}",
             robot=doc)

ROBOT_DOCS = {
    "no-modules": ('name = "t"\n', "modules"),
    "empty-modules": ('name = "t"\nmodules = []\n', "modules"),
    "name-escape": ('name = "a\\u001b[31m"\n[[modules]]\ntype = "I"\n', "name"),
    "name-newline": ('name = "a\\nb"\n[[modules]]\ntype = "I"\n', "name"),
    "name-bidi": ('name = "a\\u202eb"\n[[modules]]\ntype = "I"\n', "name"),
    "name-number": ('name = 3\n[[modules]]\ntype = "I"\n', "name"),
    "tool-far": ('name = "t"\n[tool]\nxyz = [1e6, 0, 0]\n[[modules]]\ntype = "I"\n', "tool"),
    "tool-string": ('name = "t"\n[tool]\nxyz = [0, 0, "0.3"]\n[[modules]]\ntype = "I"\n',
                    "tool.xyz[2]"),
    "base-far": ('name = "t"\n[base]\nxyz = [100, 0, 0]\n[[modules]]\ntype = "I"\n', "base"),
    "base-nan": ('name = "t"\n[base]\nxyz = [nan, 0, 0]\n[[modules]]\ntype = "I"\n', "base"),
    "home-range": ('name = "t"\nhome_deg = [400]\n[[modules]]\ntype = "I"\n', "home_deg[0]"),
    "home-length": ('name = "t"\nhome_deg = [1, 2]\n[[modules]]\ntype = "I"\n', "home_deg"),
    "home-both": ('name = "t"\nhome = [0]\nhome_deg = [0]\n[[modules]]\ntype = "I"\n', "home"),
    "unknown-key": ('name = "t"\ncolour = 1\n[[modules]]\ntype = "I"\n', "colour"),
    "redefine-I": ('name = "t"\n[module_types.I]\nlike = "II"\n[[modules]]\ntype = "I"\n',
                   "module_types.I"),
    "like-unknown": ('name = "t"\n[module_types.X]\nlike = "Z"\n[[modules]]\ntype = "X"\n',
                     "module_types.X.like"),
    "duplicate-key": ('name = "t"\nname = "u"\n[[modules]]\ntype = "I"\n', "name"),
    "not-toml": ('name = [\n', "robot"),
    "deep": ("a = " + "[" * 3000 + "]" * 3000 + "\n", "robot"),
}
for id_, (doc, field) in ROBOT_DOCS.items():
    case(f"robot-doc-{id_}", ["robot", "show", "{robot}"], field, robot=doc)
for cmd in (["robot", "urdf", "{robot}"], ["run", "preview", "--robot", "{robot}",
                                            "--out", "{out}"]):
    for id_ in ("no-modules", "tool-far", "name-bidi", "duplicate-key"):
        doc, field = ROBOT_DOCS[id_]
        case(f"{cmd[0]}-{cmd[1]}-{id_}", cmd, field, robot=doc)
case("robot-unknown-name", ["robot", "show", "mrm99"], "robot")
case("robot-missing-file", ["robot", "show", "/nonexistent/r.toml"], "robot")

# --- experiment configurations, through `mrm run table2` and `mrm run track` --------------
CONFIG_FIELDS = [
    ("experiment", "duration", ["0.0005", "-1", "nan", '"1.2"', "61.0", "0"]),
    ("experiment", "seed", ["-1", "1.5", '"0"']),
    ("experiment", "controllers", ['["pid"]', "[]", '"vdc"']),
    ("experiment", "backend", ['"fpga"', "1"]),
    ("experiment", "robot", ['"mrm99"', "3"]),
    ("experiment", "name", ['"a\\u001b[2J"', "3"]),
    ("trajectory", "amplitude", ["0.0", "nan", '"0.1"']),
    ("trajectory", "duration", ["-1.0", "0", "nan"]),
    ("trajectory", "hold", ["-0.1", "nan"]),
    ("plant", "dt", ["1e-3", "1.5e-8", "3e-5", '"1e-5"', "-1"]),
    ("plant", "current_bandwidth", ["1e-9", "0.0", "99.0", "nan"]),
    ("plant", "friction", ["1", '"yes"']),
    ("plant", "perturbation", ["0.9", '"x"']),
    ("gains", "lam", ["0", "-1", "1e6", "nan", '"200"']),
    ("gains", "k_j", ["-1", "1e6"]),
    ("gains", "K", ["-1", '"50"', "1e9"]),
    ("gains", "adapt", ["-1", "1e9"]),
    ("gains", "pid_fpga_hz", ["0", "1e6"]),
    ("gains", "friction_comp", ["-1", "3"]),
    ("gains", "pid_fpga_base_hz", ["-1", "1e6", '"5"']),
    ("gains", "pid_1khz_base_hz", ["-1", "1e6"]),
    ("gains", "vdc_base_fb", ["-0.1", "1.5", "nan"]),
    ("timing", "period_cycles", ["0", "-50000", "1.5", "25250"]),
]
for section, key, values in CONFIG_FIELDS:
    for i, value in enumerate(values):
        field = f"{section}.{key}"
        if (section, key, value) in (("plant", "dt", "3e-5"), ("timing", "period_cycles",
                                                              "25250")):
            field = "plant.dt" if key == "dt" else "timing.period_cycles"
        case(f"config-{section}-{key}-{i}", ["run", "table2", "--config", "{config}",
                                             "--out", "{out}"], field,
             config=_config_with(section, key, value))
for i, (section, key, value) in enumerate([("plant", "current_bandwidth", "1e-9"),
                                           ("experiment", "duration", "0.0005"),
                                           ("gains", "lam", "0")]):
    case(f"track-config-{i}", ["run", "track", "--config", "{config}", "--out", "{out}"],
         f"{section}.{key}", config=_config_with(section, key, value))
# the compliant plant's gear (models.gear.GearConfig): zero, negative, or unstable at the step
_COMPLIANT = _config_with("plant", "joints", '"compliant"')
for i, value in enumerate(['"soft"', "1", '""']):
    case(f"config-plant-joints-{i}", ["run", "table2", "--config", "{config}", "--out", "{out}"],
         "plant.joints", config=_config_with("plant", "joints", value))
for key, values in (("stiffness_scale", ["0", "-1", "nan", '"1"', "1e7"]),
                    ("damping_ratio", ["0", "-0.05", "1e6"]),
                    ("stiffness_spread", ["-0.1", "0.9"]),
                    ("ripple", ["-0.01", "1"]),
                    ("current_noise", ["-0.01", '"x"']),
                    ("hysteresis", ["1", '"backlash"']),
                    ("hysteresis_stiffness", ["0", "-1", "1e7"])):
    for i, value in enumerate(values):
        case(f"config-plant-gear-{key}-{i}", ["run", "table2", "--config", "{config}",
                                              "--out", "{out}"], f"plant.gear.{key}",
             config=_COMPLIANT + f"\n[plant.gear]\n{key} = {value}\n")
case("config-plant-gear-unknown", ["run", "table2", "--config", "{config}", "--out", "{out}"],
     "plant.gear.stiffness", config=_COMPLIANT + "\n[plant.gear]\nstiffness = 2.0\n")
# the holding brakes (models.brake.BrakeConfig) and the faults (cosim.experiment_config)
for key, values in (("holding_torque", ["0", "-1", '"x"']), ("slip_ratio", ["0", "1.5"]),
                    ("engage_time", ["-0.1", "2"]), ("release_time", ["nan"])):
    for i, value in enumerate(values):
        case(f"config-plant-brake-{key}-{i}", ["run", "track", "--config", "{config}",
                                               "--out", "{out}"], f"plant.brake.{key}",
             config=TABLE2 + f"\n[plant.brake]\n{key} = {value}\n")
case("config-plant-brake-unknown", ["run", "track", "--config", "{config}", "--out", "{out}"],
     "plant.brake.torque", config=TABLE2 + "\n[plant.brake]\ntorque = 1.0\n")
for i, (key, value, field) in enumerate([
        ("on_trip", '"retry"', "safety.on_trip"), ("rearm_blend", "0", "safety.rearm_blend"),
        ("line_faults", '"cut:down:1@1ms"', "safety.line_faults"),
        ("line_faults", '["cut:sideways:1@1ms"]', "safety.line_faults"),
        ("line_faults", '["cut:down:1@1ms+forever"]', "safety.line_faults"),
        ("colour", "1", "safety.colour"), ("standstill", "-0.01", "safety.standstill"),
        ("standstill", "50.0", "safety.standstill"), ("standstill_s", "0.5", "safety.standstill_s"),
        ("stop_s", "1e6", "safety.stop_s"), ("hold_hz", "0", "safety.hold_hz"),
        ("stop_trail", "-1.0", "safety.stop_trail"), ("stop_trail", "100", "safety.stop_trail"),
        ("stop_trail", "nan", "safety.stop_trail")]):
    case(f"config-safety-{i}", ["run", "track", "--config", "{config}", "--out", "{out}"],
         field, config=TABLE2 + f"\n[safety]\n{key} = {value}\n")
case("track-model-bit-fault", ["run", "track", "--config", "{config}", "--backend", "model",
                               "--out", "{out}"], "safety.line_faults",
     config=TABLE2 + '\n[safety]\nline_faults = ["bit:up:1@1ms"]\n')
case("track-fault-node-beyond-robot", ["run", "track", "--line-fault", "cut:down:4@1ms",
                                       "--backend", "model", "--out", "{out}"], "--line-fault")
case("config-unknown-section", ["run", "table2", "--config", "{config}", "--out", "{out}"],
     "colour", config=TABLE2 + "\n[colour]\nred = 1\n")
case("config-duplicate-key", ["run", "table2", "--config", "{config}", "--out", "{out}"],
     "experiment.seed", config=TABLE2.replace("seed = 0 ", "seed = 0\nseed = 1 ", 1))
case("config-not-utf8", ["run", "table2", "--config", "{config}", "--out", "{out}"],
     "--config", config="name = 'M\udcfcller'\n")
case("config-missing", ["run", "table2", "--config", "/nonexistent/c.toml", "--out", "{out}"],
     "--config")

# --- command-line flags of the run commands ----------------------------------------------
FLAGS = [
    (["run", "table2", "--duration", "0.0005"], "--duration"),
    (["run", "table2", "--duration", "-1"], "--duration"),
    (["run", "table2", "--duration", "nan"], "--duration"),
    (["run", "table2", "--seed", "-1"], "--seed"),
    (["run", "table2", "--seed", "x"], "--seed"),
    (["run", "table2", "--jobs", "0"], "--jobs"),
    (["run", "table2", "--backend", "fpga"], "--backend"),
    (["run", "table2", "--seed", "1", "--seed", "2"], "--seed"),
    (["run", "table2", "--threads", "0"], "--threads"),
    (["run", "table2", "--threads", "1", "--threads", "2"], "--threads"),
    (["run", "track", "--threads", "x"], "--threads"),
    (["run", "line", "{line}", "--threads", "-1"], "--threads"),
    (["run", "dmp-table2", "--threads", "1.5"], "--threads"),
    (["run", "track", "--controller", "lqr"], "--controller"),
    (["run", "track", "--duration", "0"], "--duration"),
    (["run", "track", "--robot", "mrm99"], "--robot"),
    (["run", "track", "--backend", "model", "--line-fault", "bit:up:1@1ms"], "--line-fault"),
    (["run", "track", "--line-fault", "zap:up:1@1ms"], "--line-fault"),
    (["run", "track", "--signals", "torque*"], "--signals"),
    (["run", "track", "--vcd", "x:y", "--backend", "compiled"], "--vcd"),
    (["run", "track", "--fst", "x:y", "--backend", "compiled"], "--fst"),
    (["run", "track", "--fst", "2ms:1ms", "--backend", "pysim"], "--fst"),
    (["run", "track", "--fst", "0:1ms", "--backend", "model"], "--fst"),
    (["run", "track", "--vcd", "0:1ms", "--backend", "model"], "--vcd"),
    (["run", "track", "--fst", "0:1ms", "--vcd", "0:1ms", "--backend", "pysim"], "--fst"),
    (["run", "track", "--fst", "0:1ms", "--backend", "pysim", "--signals", "torque*,,"],
     "--signals"),
    (["run", "track", "--fst", "0:1ms", "--fst", "0:2ms"], "--fst"),
    (["run", "preview", "--duration", "0.001"], "--duration"),
    (["run", "preview", "--duration", "-1"], "--duration"),
    (["run", "preview", "--robot", "mrm99"], "--robot"),
    (["run", "preview", "--uncertainty", "nan"], "--uncertainty"),
    (["run", "line", "{line}", "--robot", "mrm3"], "--robot"),
    (["run", "line", "{line}", "--profile", "fast"], "--profile"),
    (["run", "line", "{line}", "--duration", "-1"], "--duration"),
    (["run", "line", "/nonexistent/line.toml"], "FILE"),
    (["bench", "--backend", "fpga"], "--backend"),
    (["bench", "--robot", "mrm99"], "--robot"),
    (["bench", "--threads", "0"], "--threads"),
    (["sweep", "spec.toml", "--threads", "0", "--out", "{out}"], "--threads"),
    (["tune", "spec.toml", "--threads", "two", "--out", "{out}"], "--threads"),
    (["cache", "prune", "--older-than", "-1"], "--older-than"),
    (["cache", "prune", "--older-than", "nan"], "--older-than"),
    (["cache", "prune", "--older-than", "a week"], "--older-than"),
    (["cache", "prune", "--all", "--kind", "pip"], "--kind"),
    (["cache", "prune", "--all", "--older-than", "3"], "--older-than"),
]
for i, (argv, field) in enumerate(FLAGS):
    needs_out = argv[0] == "run"
    case(f"flag-{argv[1]}-{i}", argv + (["--out", "{out}"] if needs_out else []), field,
         **({"line": LINE} if "{line}" in argv else {}))

# A waveform goes into the result folder: a place where none can be written is refused
# before the run, naming --out (the FST or VCD is never half-written).
case("wave-fst-out-proc", ["run", "track", "--fst", "0:1us", "--out", "/proc/mrm-waves"], "--out")
case("wave-vcd-out-file", ["run", "track", "--vcd", "0:1us", "--out", str(ROOT / "README.md")],
     "--out")

# --- Cartesian lines, through `mrm plan line` and `mrm run line` ---------------------------
LINE_EDITS = [
    ("translation = { velocity = 0.2,", "translation = { velocity = -0.1,",
     "limits.translation.velocity"),
    ("translation = { velocity = 0.2,", 'translation = { velocity = "0.1",',
     "limits.translation.velocity"),
    ("translation = { velocity = 0.2,", "translation = { velocity = 0,",
     "limits.translation.velocity"),
    ("translation = { velocity = 0.2,", "translation = { velocity = nan,",
     "limits.translation.velocity"),
    ("translation = { velocity = 0.2,", "translation = { velocity = 1e-300,",
     "limits.translation.velocity"),
    ("[limits]", "[limit]", "limit"),
    ("[end]", "[stop]", "stop"),
]
for i, (old, new, field) in enumerate(LINE_EDITS):
    for cmd in (["plan", "line", "{line}"], ["run", "line", "{line}", "--out", "{out}"]):
        case(f"line-{cmd[0]}-{i}", cmd, field, line=_line_with(old, new))
case("line-duplicate", ["plan", "line", "{line}"], "limits",
     line=LINE + "\n[limits]\nx = 1\n")
case("line-quintic-tf", ["plan", "quintic", "--q0", "0", "--qf", "1", "--tf", "0"], "--tf")
case("line-quintic-nan", ["plan", "quintic", "--q0", "nan", "--qf", "1", "--tf", "1"], "--q0")
case("line-samples-dt", ["plan", "line", "{line}", "--samples", "{out}", "--dt", "-1"], "--dt",
     line=LINE)

# --- gateware generation --------------------------------------------------------------------
HDL = [
    (["--top", "cpu"], "--top"),
    (["--top", "spw_codec", "--param", "slots"], "--param"),
    (["--top", "spw_codec", "--param", "slots=x"], "--param slots"),
    (["--top", "spw_codec", "--param", "slots=1", "--param", "slots=2"], "--param slots"),
    (["--top", "spw_codec", "--param", "colour=1"], "--param"),
    (["--top", "spw_codec", "--param", "reset_cycles=99999999999999999999"],
     "--param reset_cycles"),
    (["--top", "spw_codec", "--param", "rx_fifo_depth=1000000"], "--param rx_fifo_depth"),
    (["--top", "spw_codec", "--param", "rx_fifo_depth=2"], "--param"),
    (["--top", "system", "--param", "n_nodes=0"], "--param"),
    (["--top", "system", "--param", "n_nodes=99"], "--param"),
    (["--top", "node", "--param", "counts_per_rev=1"], "--param counts_per_rev"),
]
for i, (argv, field) in enumerate(HDL):
    case(f"hdl-verilog-{i}", ["hdl", "verilog", *argv, "--out", "{out}"], field)


# --- sweep specifications, through `mrm sweep` (issue 19; cases after the other sweep
# implementation's, branch `sweep`, in this spec's format) ------------------------------
_AXIS = '[[axis]]\nfield = "{}"\n{}\n'
SWEEPS = [
    (_AXIS.format("gains.lamda", "values = [1.0, 2.0]"), "axis[0].field"),
    (_AXIS.format("gains.K", "values = [50.0, 6000.0]"), "axis[0].field"),
    (_AXIS.format("experiment.seed", "values = [1, 2]"), "axis[0].field"),
    (_AXIS.format("gains.lam", "values = [100.0, 100.0]"), "axis[0].values"),
    (_AXIS.format("gains.lam", "range = { start = 100.0, stop = 200.0, num = 0 }"),
     "axis[0].range.num"),
    (_AXIS.format("plant.dt", "range = { start = 0.0, stop = 1e-5, num = 3, log = true }"),
     "axis[0].range"),
    (_AXIS.format("gains.lam", 'values = [1.0]\nrange = { start = 1.0, stop = 2.0, num = 2 }'),
     "axis[0]"),
    ('[sweep]\nseeds = [-1, 2]\n', "sweep.seeds"),
    ('[sweep]\nseeds = { start = 5, count = 0 }\n', "sweep.seeds.count"),
    ('[sweep]\ncontrollers = ["vdc", "pid-2khz"]\n', "sweep.controllers"),
    ('[sweep]\nbackends = ["verilator"]\n', "sweep.backends"),
    ('[sweep]\nkind = "dmp"\n', "sweep.kind"),
    ('[sweep]\nruns = 3\n', "sweep.runs"),
    ('[sweep]\nconfig = "/nonexistent/e.toml"\n', "sweep.config"),
    ('[sweep]\nduration = -1.0\n', "sweep.duration"),
    ('[draws]\nmethod = "sobol"\ncount = 4\nfields = { "gains.lam" = [1.0, 2.0] }\n',
     "draws.method"),
    ('[draws]\nmethod = "lhs"\ncount = 4\nfields = { "gains.lam" = [2.0, 1.0] }\n',
     "draws.fields.gains.lam"),
    ('[draws]\nmethod = "lhs"\ncount = 4\nfields = { "plant.friction" = [0, 1] }\n',
     "draws.fields.plant.friction"),
    ('[draws]\nmethod = "random"\ncount = 0\nfields = { "gains.K" = [1.0, 2.0] }\n',
     "draws.count"),
    ('[axes]\n"gains.lam" = [1.0]\n', "axes"),
]
for i, (text, field) in enumerate(SWEEPS):
    case(f"sweep-spec-{i}", ["sweep", "{spec}", "--out", "{out}"], field, spec=text)
for i, (flags, field) in enumerate([(["--workers", "0"], "--workers"),
                                    (["--scheduler", "http://host:8786"], "--scheduler")]):
    case(f"sweep-flag-{i}", ["sweep", "{spec}", "--out", "{out}", *flags], field,
         spec='[sweep]\nduration = 0.01\n')
case("sweep-missing-spec", ["sweep", "/nonexistent/s.toml", "--out", "{out}"], "SPEC")

# --- fault campaigns, `mrm sweep` of kind "link-faults" (issue 22 item 4) -------------------
_LF = '[sweep]\nkind = "link-faults"\n'
_LOOP = _LF + '[campaign]\nlevel = "loop"\n'
CAMPAIGNS = [
    (_LF, "campaign"),
    (_LF + '[campaign]\nlevel = "chip"\n', "campaign.level"),
    (_LF + '[campaign]\nkinds = ["bit", "emp"]\n', "campaign.kinds"),
    (_LF + '[campaign]\nkinds = ["bit", "bit"]\n', "campaign.kinds"),
    (_LF + '[campaign]\nkinds = []\n', "campaign.kinds"),
    (_LF + '[campaign]\nfaults = -5\n', "campaign.faults"),
    (_LF + '[campaign]\nfaults = 100\nchunk = 0\n', "campaign.chunk"),
    (_LF + '[campaign]\ncredit_timeout = -1\n', "campaign.credit_timeout"),
    (_LF + '[campaign]\ncredit_audit = 1\n', "campaign.credit_audit"),
    (_LF + '[campaign]\nrx_fifo_depth = 8\n', "campaign.rx_fifo_depth"),
    (_LF + '[campaign]\nduration = 0.01\n', "campaign.duration"),
    (_LF + 'seeds = [1]\n[campaign]\n', "sweep.seeds"),
    (_LF + '[campaign]\n[[axis]]\nfield = "gains.lam"\nvalues = [1.0]\n', "axis"),
    (_LOOP + 'backend = "model"\n', "campaign.backend"),
    (_LOOP + 'duration = -0.01\n', "campaign.duration"),
    (_LOOP + 'kinds = ["lost-fct"]\n', "campaign.kinds"),
    (_LOOP + 'window = [0.008, 0.004]\n', "campaign.window"),
    (_LOOP + 'faults_per_run = 20\n', "campaign.faults_per_run"),
    (_LOOP + 'cycles = [0, 100]\n', "campaign.cycles"),
    (_LOOP + 'cycles = [-10, 100]\n', "campaign.cycles"),
    (_LOOP + 'seeds = [-1]\n', "campaign.seeds"),
    (_LOOP + 'controller = "lqr"\n', "campaign.controller"),
    (_LOOP + 'config = "/nonexistent/e.toml"\n', "campaign.config"),
    (_LOOP + 'faults = 100\n', "campaign.faults"),
]
for i, (text, field) in enumerate(CAMPAIGNS):
    case(f"sweep-campaign-{i}", ["sweep", "{spec}", "--out", "{out}"], field, spec=text)

case("sweep-out-is-a-file", ["sweep", "{spec}", "--out", "{spec}"], "--out",
     spec='[sweep]\nduration = 0.01\n')


# --- tuning specifications, through `mrm tune` (issue 20 item 3) -----------------------------
_TUNE = ('[tune]\nseeds = {seeds}\namplitudes = {amps}\ntrajectory_duration = {tf}\n'
         'hold = 0.11\nbudget = {budget}\ninitial = 1\ncontrollers = ["pid-fpga"]\n{extra}'
         '\n[tune.space.pid-fpga]\n"gains.pid_fpga_hz" = {space}\n')


def _tune(seeds="[3000]", amps="[0.002]", tf="0.02", budget="2", extra="",
          space="[5.0, 20.0]"):
    return _TUNE.format(seeds=seeds, amps=amps, tf=tf, budget=budget, extra=extra, space=space)


TUNES = [
    (_tune(seeds="[0]"), "tune.seeds"),                          # the headline table's plant
    (_tune(seeds="[3000, 1005]", extra='held_out = ["' + str(ROOT / "configs" / "sweeps" /
                                                             "table2-seeds.toml") + '"]\n'),
     "tune.seeds"),                                              # a held-out test plant
    (_tune(amps="[0.1571]", tf="1.0"), "tune.amplitudes[0]"),    # the test's quintic
    (_tune(budget="0"), "tune.budget"),
    (_tune(space="[20.0, 5.0]"), "tune.space.pid-fpga.gains.pid_fpga_hz"),
    (_tune(space="[5.0, 500.0]"), "tune.space.pid-fpga.gains.pid_fpga_hz"),
    (_tune(extra='held_out = ["/nonexistent/s.toml"]\n'), "tune.held_out[0]"),
    (_tune(extra="budgett = 3\n"), "tune.budgett"),
    (_tune(extra="[tune.set]\n\"plant.joints\" = \"elastic\"\n"), "tune.set.plant.joints"),
]
for i, (text, field) in enumerate(TUNES):
    case(f"tune-spec-{i}", ["tune", "{spec}", "--out", "{out}"], field, spec=text)
case("tune-flag-workers", ["tune", "{spec}", "--out", "{out}", "--workers", "0"], "--workers",
     spec=_tune())


# --- DMP learning and rollout, through `mrm dmp learn` and `mrm dmp rollout` (issue 17) -------
def _joint_csv(rows: int = 21, dt: float = 0.05) -> str:
    lines = ["t,q1,q2"]
    for k in range(rows):
        u = k / (rows - 1)
        lines.append(f"{k * dt!r},{u * u * (3 - 2 * u)!r},{0.5 * u!r}")
    return "\n".join(lines) + "\n"


def _cartesian_csv() -> str:
    """Five poses of mrm6's tool near home (FK of small joint steps), 10 ms apart."""
    import numpy as np

    from mrm_cosim.master.kinematics import forward
    from mrm_cosim.master.quaternion import from_matrix
    from mrm_cosim.models.robot import load_robot

    robot = load_robot("mrm6")
    lines = ["t,x,y,z,qw,qx,qy,qz"]
    for k in range(5):
        T = forward(robot, robot.home + 0.01 * k * np.array([1, -1, 1, 0.5, 1, -1]))
        cells = [0.01 * k, *T[:3, 3], *from_matrix(T[:3, :3])]
        lines.append(",".join(repr(float(c)) for c in cells))
    return "\n".join(lines) + "\n"


def _dmp_toml() -> str:
    import numpy as np

    from mrm_cosim.master.dmp import learn_dmp
    from mrm_cosim.master.dmp_file import dmp_toml

    data = np.array([[float(c) for c in row.split(",")] for row in
                     JOINT_CSV.splitlines()[1:]])
    return dmp_toml(learn_dmp(data[:, 1:], 0.05, 5), {"source": "corpus"})


JOINT_CSV = _joint_csv()
CART_CSV = _cartesian_csv()
DMP_TOML = _dmp_toml()


def _row_edit(text: str, line: int, column: int, value: str) -> str:
    """``text`` with the cell at 1-based ``line`` and 0-based ``column`` replaced."""
    lines = text.splitlines()
    cells = lines[line - 1].split(",")
    cells[column] = value
    lines[line - 1] = ",".join(cells)
    return "\n".join(lines) + "\n"


_LEARN = ["dmp", "learn", "{traj_csv}", "--basis", "5", "--out", "{out}"]
DMP_LEARN_FILES = [
    ("header-time", JOINT_CSV.replace("t,q1,q2", "time,q1,q2"), "TRAJ line 1"),
    ("header-dup", JOINT_CSV.replace("t,q1,q2", "t,q1,q1"), "TRAJ line 1"),
    ("header-empty-name", JOINT_CSV.replace("t,q1,q2", "t,,q2"), "TRAJ line 1"),
    ("header-only-t", "t\n0\n1\n2\n", "TRAJ line 1"),
    ("empty", "", "TRAJ"),
    ("two-rows", "t,q1\n0,0\n0.1,1\n", "TRAJ"),
    ("nonuniform", _row_edit(JOINT_CSV, 5, 0, "0.16"), "TRAJ line 5"),
    ("not-increasing", _row_edit(JOINT_CSV, 5, 0, "0.1"), "TRAJ line 5"),
    ("nan", _row_edit(JOINT_CSV, 3, 1, "nan"), "TRAJ line 3 column q1"),
    ("inf", _row_edit(JOINT_CSV, 4, 2, "-inf"), "TRAJ line 4 column q2"),
    ("text", _row_edit(JOINT_CSV, 6, 2, "0.1rad"), "TRAJ line 6 column q2"),
    ("ragged", JOINT_CSV.replace("\n0.1,", "\n0.1,0,", 1), "TRAJ line 4"),
]
for id_, text, field in DMP_LEARN_FILES:
    case(f"dmp-learn-{id_}", _LEARN, field, traj_csv=text)
DMP_LEARN_FLAGS = [
    (["--basis", "0"], "--basis"), (["--basis", "1"], "--basis"),
    (["--basis", "2.5"], "--basis"), (["--basis", "ten"], "--basis"),
    (["--alpha", "-1"], "--alpha"), (["--alpha", "nan"], "--alpha"),
    (["--alpha-s", "0"], "--alpha-s"), (["--overlap", "1"], "--overlap"),
    (["--overlap", "x"], "--overlap"),
    (["--columns", "q1,q7"], "--columns"), (["--columns", "q1,,q2"], "--columns"),
    (["--columns", "q1,q1"], "--columns"), (["--columns", "t"], "--columns"),
    (["--robot", "mrm6"], "--robot"),
    (["--alpha", "2000"], "TRAJ"),                     # k·α > 1.66 at the demo's step
]
for i, (flags, field) in enumerate(DMP_LEARN_FLAGS):
    case(f"dmp-learn-flag-{i}", ["dmp", "learn", "{traj_csv}", "--basis", "5", *flags,
                                 "--out", "{out}"], field, traj_csv=JOINT_CSV)
case("dmp-learn-no-basis", ["dmp", "learn", "{traj_csv}", "--out", "{out}"], "--basis",
     traj_csv=JOINT_CSV)
case("dmp-learn-missing", ["dmp", "learn", "/nonexistent/t.csv", "--basis", "5", "--out",
                           "{out}"], "TRAJ")
case("dmp-learn-out-is-input", ["dmp", "learn", "{traj_csv}", "--basis", "5", "--out",
                                "{traj_csv}"], "--out", traj_csv=JOINT_CSV)
case("dmp-learn-out-is-a-folder", ["dmp", "learn", "{traj_csv}", "--basis", "5", "--out",
                                   "/"], "--out", traj_csv=JOINT_CSV)
case("dmp-learn-out-no-folder", ["dmp", "learn", "{traj_csv}", "--basis", "5", "--out",
                                 "/nonexistent/d.toml"], "--out", traj_csv=JOINT_CSV)
_CART = ["dmp", "learn", "{traj_csv}", "--cartesian", "--basis", "5", "--out", "{out}"]
case("dmp-learn-cartesian-unreachable", _CART, "TRAJ line 4",
     traj_csv=_row_edit(CART_CSV, 4, 1, "5.0"))
case("dmp-learn-cartesian-unreachable-first", _CART, "TRAJ line 2",
     traj_csv=_row_edit(CART_CSV, 2, 3, "-3.0"))
case("dmp-learn-cartesian-quaternion", _CART, "TRAJ line 3",
     traj_csv=_row_edit(CART_CSV, 3, 4, "2.0"))
case("dmp-learn-cartesian-columns", _CART, "TRAJ line 1",
     traj_csv=CART_CSV.replace(",qz", ",q_z", 1))
case("dmp-learn-cartesian-mrm3", [*_CART, "--robot", "mrm3"], "--robot", traj_csv=CART_CSV)
case("dmp-learn-cartesian-no-robot", [*_CART, "--robot", "mrm99"], "--robot",
     traj_csv=CART_CSV)
case("dmp-learn-cartesian-and-columns", [*_CART, "--columns", "x"], "--columns",
     traj_csv=CART_CSV)

_ROLL = ["dmp", "rollout", "{dmp}", "--samples", "{out}"]
DMP_ROLLOUT_FLAGS = [
    (["--tau", "0"], "--tau"), (["--tau", "-1"], "--tau"), (["--tau", "nan"], "--tau"),
    (["--tau", "fast"], "--tau"),
    (["--goal", "1"], "--goal"), (["--goal", "1,2,3"], "--goal"),
    (["--goal", "1,x"], "--goal[1]"), (["--goal", "1,inf"], "--goal"),
    (["--dt", "0"], "--dt"), (["--dt", "0.5"], "--dt"),
    (["--tau", "0.01", "--dt", "0.001"], "--dt"),            # k·α = 2.5: would diverge
    (["--plot", "/"], "--plot"), (["--plot", "{dmp}"], "--plot"),
    (["--duration", "-1"], "--duration"), (["--duration", "0.0001"], "--dt"),
]
for i, (flags, field) in enumerate(DMP_ROLLOUT_FLAGS):
    case(f"dmp-rollout-flag-{i}", [*_ROLL, *flags], field, dmp=DMP_TOML)
case("dmp-rollout-samples-is-input", ["dmp", "rollout", "{dmp}", "--samples", "{dmp}"],
     "--samples", dmp=DMP_TOML)
case("dmp-rollout-samples-is-a-folder", ["dmp", "rollout", "{dmp}", "--samples", "/"],
     "--samples", dmp=DMP_TOML)
case("dmp-rollout-missing", ["dmp", "rollout", "/nonexistent/d.toml", "--samples", "{out}"],
     "DMP")


def _dmp_with(old: str, new: str) -> str:
    assert old in DMP_TOML, old
    return DMP_TOML.replace(old, new, 1)


DMP_FILES = [
    ("not-toml", "format = [\n", "DMP"),
    ("format", _dmp_with('format = "mrm-dmp"', 'format = "dmp"'), "format"),
    ("version", _dmp_with("version = 1", "version = 2"), "version"),
    ("unknown-top", "colour = 1\n" + DMP_TOML, "colour"),
    ("unknown-key", _dmp_with("alpha = 25.0", "alpha = 25.0\ngamma = 1.0"), "dmp.gamma"),
    ("missing-key", _dmp_with("alpha_s = 2.0\n", ""), "dmp.alpha_s"),
    ("tau-negative", _dmp_with("tau = ", "tau = -"), "dmp.tau"),
    ("tau-string", _dmp_with("tau = 1.0", 'tau = "1.0"'), "dmp.tau:"),
    ("alpha-nan", _dmp_with("alpha = 25.0", "alpha = nan"), "dmp.alpha"),
    ("x0-count", _dmp_with("x0 = [", "x0 = [0.0, "), "dmp.x0"),
    ("g-text", _dmp_with("g = [", 'g = ["a", '), "dmp.g"),
    ("goal-scaling", _dmp_with("goal_scaling = [true", "goal_scaling = [1"),
     "dmp.goal_scaling[0]"),
    ("widths-negative", _dmp_with("widths = [", "widths = [-"), "dmp.widths[0]"),
    ("centers-one", "\n".join("centers = [0.5]" if line.startswith("centers =") else line
                               for line in DMP_TOML.splitlines()), "dmp.centers:"),
    ("widths-count", _dmp_with("widths = [", "widths = [0.5, "), "dmp.widths"),
    ("weights-row", _dmp_with("weights = [\n    [", "weights = [\n    [1.0, "),
     "dmp.weights[0]"),
    ("weights-inf", _dmp_with("weights = [\n    [", "weights = [\n    [inf, "),
     "dmp.weights[0]"),
    ("no-dmp-table", 'format = "mrm-dmp"\nversion = 1\n', "dmp"),
]
for id_, text, field in DMP_FILES:
    case(f"dmp-file-{id_}", _ROLL, field, dmp=text)

# --- the motion-primitive comparison, through `mrm run dmp-table2` -------------------------
# Every refusal comes before any run: the configuration, the paths through IK, the primitives
# against the node's word formats.
DMP_TABLE2 = (ROOT / "configs" / "dmp_table2.toml").read_text()


def _dmp_table2_with(old: str, new: str) -> str:
    assert old in DMP_TABLE2, old
    return DMP_TABLE2.replace(old, new, 1)


DMP_TABLE2_EDITS = [
    ("periods_ms = [50, 10]", "periods_ms = [50, 50]", "experiment.periods_ms"),
    ("periods_ms = [50, 10]", "periods_ms = [0]", "experiment.periods_ms"),
    ("periods_ms = [50, 10]", "periods_ms = 50", "experiment.periods_ms"),
    ('controller = "pid-fpga"', 'controller = "vdc"', "experiment.controller"),
    ("hold = 0.2", "hold = -1", "experiment.hold"),
    ("basis = 30", "basis = 1", "dmp.basis"),
    ("basis = 30", "basis = 40", "dmp.joint1.weights"),
    ("alpha = 25.0", "alpha = -25.0", "dmp.alpha"),
    ("alpha = 25.0", "alpha = 5000.0", "dmp.alpha"),
    ("scaling_min = 0.2", "scaling_min = 1.5", "dmp.scaling_min"),
    ("scaling_min = 0.2", "scaling_min = 0.0", "dmp.joint3.weights"),
    ("step_cycles = 50000", "step_cycles = 30000", "dmp.step_cycles"),
    ("step_cycles = 50000", "step_cycles = 10", "dmp.step_cycles"),
    ("e1 = [-1.0, 0.0, 0.0]", "e1 = [-1.0, 0.0]", "plane.e1"),
    ("e2 = [0.0, 1.0, 0.0]", "e2 = [-1.0, 1.0, 0.0]", "path half8.e2"),
    ('shape = "half8"', 'shape = "spiral"', "path[0].shape"),
    ("size = 0.06 ", "radius = 0.06 ", "path[0].radius"),
    ("size = 0.06 ", "size = -0.06 ", "path half8.size"),
    ("size = 0.06 ", "size = 0.6 ", "path"),
    ("radius = 0.04", "radius = 0.4", "path"),
    ('name = "circle"', 'name = "half8"', "path[1].name"),
    ("duration = 2.5 ", "duration = 0 ", "path[0].duration"),
    ("[plane]", "[planes]", "planes"),
    ("[gains]", "[gains]\nlam = -1", "gains.lam"),
]
for i, (old, new, field) in enumerate(DMP_TABLE2_EDITS):
    case(f"dmp-table2-config-{i}", ["run", "dmp-table2", "--config", "{cfg}", "--out", "{out}"],
         field, cfg=_dmp_table2_with(old, new))
for i, (flags, field) in enumerate([
        (["--robot", "mrm3"], "--robot"), (["--robot", "mrm99"], "--robot"),
        (["--path", "spiral"], "--path"), (["--jobs", "0"], "--jobs"),
        (["--backend", "fpga"], "--backend"), (["--seed", "-1"], "--seed"),
        (["--config", "/nonexistent/dmp.toml"], "--config")]):
    case(f"dmp-table2-flag-{i}", ["run", "dmp-table2", *flags, "--out", "{out}"], field)
