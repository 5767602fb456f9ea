"""``mrm robot``: inspect a robot assembly (built-in name or TOML file) and export its URDF."""

from __future__ import annotations

import json
import math
import sys


def register(subparsers) -> None:
    p = subparsers.add_parser("robot", help="show a robot assembly or export its URDF",
                              epilog="example:\n  mrm robot show mrm3 --json")
    sub = p.add_subparsers(dest="robot_command", required=True)
    p_show = sub.add_parser("show", help="describe an assembly: modules, geometry, parameters",
                            epilog="example:\n  mrm robot show mrm6\n  mrm robot show "
                            "my_arm.toml --json")
    p_show.add_argument("robot", help="built-in name (mrm3, mrm6) or path to an assembly .toml")
    p_show.add_argument("--json", action="store_true", help="machine-readable output")
    p_show.set_defaults(func=_show)
    p_urdf = sub.add_parser("urdf", help="print the assembly's URDF on stdout",
                            epilog="example:\n  mrm robot urdf mrm3 > mrm3.urdf")
    p_urdf.add_argument("robot", help="built-in name (mrm3, mrm6) or path to an assembly .toml")
    p_urdf.set_defaults(func=_urdf)
    p_list = sub.add_parser("list", help="list the built-in assemblies",
                            epilog="example:\n  mrm robot list")
    p_list.set_defaults(func=_list)


def _show(args) -> int:
    from mrm_cosim.models.robot import load_robot

    robot = load_robot(args.robot)
    info = robot.describe()
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"{info['name']}: {info['n_modules']} modules, {info['total_mass_kg']:.2f} kg")
    print(f"  base xyz {info['base']['xyz']} m, rpy "
          f"{[round(math.degrees(a), 3) for a in info['base']['rpy']]} deg")
    print(f"  tool xyz {info['tool']['xyz']} m in T{info['n_modules']}")
    print(f"  home {[round(a, 3) for a in info['home_deg']]} deg")
    for m in info["modules"]:
        spring = ("-" if m["spring"] is None else
                  f"{m['spring']['torque_Nm']:g} N·m cos(q{m['spring']['phase_deg']:+g}°)")
        print(f"  {m['index']}: type {m['type']:<3} {m['actuator']:<12} twist "
              f"{m['twist_deg']:+6.1f}°  L_b {m['length_b_m']:.3f} m  L_a {m['length_a_m']:.3f} m"
              f"  peak {m['peak_torque_Nm']:g} N·m  cont {m['continuous_torque_Nm']:g} N·m"
              f"  {m['counts_per_rev']} counts/rev  spring {spring}")
    return 0


def _urdf(args) -> int:
    from mrm_cosim.models.robot import load_robot

    sys.stdout.write(load_robot(args.robot).urdf())
    return 0


def _list(args) -> int:
    from mrm_cosim.models.robot import builtin_robots

    for name in builtin_robots():
        print(name)
    return 0
