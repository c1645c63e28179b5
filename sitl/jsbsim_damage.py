"""The JSBSim aircraft a fault flies: the installed model's XML, copied at run time with fault properties in it.

JSBSim computes each aerodynamic coefficient from a function of its XML (``<aerodynamics>/<axis>/<function>``).  A
fault that changes the aircraft itself needs a multiplier inside those functions, so :func:`write_model` copies
the model's folder (``aircraft/MODEL/``, from the installed wheel) into a temporary folder and rewrites the copy
of ``MODEL.xml`` (nothing is committed, nothing of the installed wheel is changed):

- every coefficient function of an ``<axis>`` that reads the surface's position (a property with
  ``aileron-pos`` or ``rudder-pos`` in its name: on the c172x ``CYda``, ``Clda``, ``Cnda`` or ``CYdr``, ``Cldr``,
  ``Cndr``) becomes ``<product> fault/control-effectiveness  (the function as it was) </product>``;
- every function of the ``ROLL`` axis that reads the roll rate (``velocities/p-aero-rad_sec``: the c172x's ``Clp``,
  the roll damping) becomes ``<product> fault/roll-damping  (the function) </product>``;
- both properties are declared in ``<aerodynamics>`` with the value 1 (a product with 1 is exact: until a fault
  starts the copy flies bit for bit like the installed model, ``tests/sitl/test_faults_jsbsim.py``);
- three point masses of weight 0 are appended to ``<mass_balance>`` (``BALLAST``): the ``inertia`` and ``cg``
  faults give them weight at run time (``inertia/pointmass-weight-lbs[i]``, JSBSim recomputes the CG and the
  inertia tensor every step).

The plant loads the copy with ``FGFDMExec.load_model_with_paths`` (the copy's folder as the aircraft path, the
wheel's engines and systems) and deletes it once loaded.  This module reads and writes files (the copy); the
decisions are the pure ``sitl.damage``'s.
"""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

EFFECTIVENESS = "fault/control-effectiveness"
DAMPING = "fault/roll-damping"
BALLAST = ("FAULT BALLAST LEFT", "FAULT BALLAST RIGHT", "FAULT BALLAST CG")
ROLL_RATE = ("velocities/p-aero-rad_sec", "velocities/p-rad_sec")
SURFACE_KEYS = {"aileron": "aileron-pos", "rudder": "rudder-pos"}
SLUG_LB = 32.174049  # lb per slug (JSBSim's slugtolb): a point mass's weight in lb is its mass in slug times this


@dataclass(frozen=True)
class Anatomy:
    """What a model's XML offers the faults: the functions each multiplier goes into, its point masses (the ballast
    comes after them), the wing span (ft)."""

    effectiveness: tuple[str, ...]
    damping: tuple[str, ...]
    pointmasses: int
    span_ft: float | None


def _properties(el) -> list[str]:
    return [(p.text or "").strip() for p in el.iter("property")]


def _coefficients(root, surface: str):
    """(the surface's functions, the roll-damping functions) of the ``<axis>`` elements."""
    key = SURFACE_KEYS[surface]
    control, damping = [], []
    aero = root.find("aerodynamics")
    for axis in aero.iter("axis") if aero is not None else ():
        for fn in axis.findall("function"):
            props = _properties(fn)
            if any(key in p for p in props):
                control.append(fn)
            if axis.get("name", "").upper() == "ROLL" and any(p in ROLL_RATE for p in props):
                damping.append(fn)
    return control, damping


def _span_ft(root) -> float | None:
    el = root.find("metrics/wingspan")
    try:
        v = float((el.text or "").strip()) if el is not None else None
    except ValueError:
        return None
    if v is None:
        return None
    unit = (el.get("unit") or "FT").upper()
    return v / 12.0 if unit == "IN" else v * 3.280839895 if unit == "M" else v


def anatomy(xml_path: str | Path, surface: str) -> Anatomy:
    """Read a model's XML: where the faults' multipliers and ballast go."""
    root = ET.parse(xml_path).getroot()
    control, damping = _coefficients(root, surface)
    mb = root.find("mass_balance")
    return Anatomy(
        tuple(f.get("name", "?") for f in control),
        tuple(f.get("name", "?") for f in damping),
        0 if mb is None else len(mb.findall("pointmass")),
        _span_ft(root),
    )


def _wrap(fn, prop: str) -> None:
    """The function's operation (its one element that is not the description) inside a product with ``prop``."""
    ops = [c for c in fn if c.tag != "description"]
    product = ET.Element("product")
    p = ET.SubElement(product, "property")
    p.text = prop
    for op in ops:
        fn.remove(op)
        product.append(op)
    fn.append(product)


def _ballast(name: str) -> ET.Element:
    pm = ET.Element("pointmass", name=name)
    w = ET.SubElement(pm, "weight", unit="LBS")
    w.text = "0.0"
    loc = ET.SubElement(pm, "location", unit="IN")
    for axis in ("x", "y", "z"):
        ET.SubElement(loc, axis).text = "0.0"
    return pm


def write_model(src: str | Path, dst: str | Path, model: str, surface: str) -> Anatomy:
    """Copy ``src`` (the model's folder) to ``dst/MODEL`` and rewrite ``MODEL.xml`` there (module docstring)."""
    out = Path(dst) / model
    shutil.copytree(src, out)
    path = out / f"{model}.xml"
    tree = ET.parse(path)
    root = tree.getroot()
    control, damping = _coefficients(root, surface)
    for fn in control:
        _wrap(fn, EFFECTIVENESS)
    for fn in damping:
        _wrap(fn, DAMPING)
    aero = root.find("aerodynamics")
    for prop in (DAMPING, EFFECTIVENESS):
        el = ET.Element("property", value="1.0")
        el.text = prop
        aero.insert(0, el)
    mb = root.find("mass_balance")
    n = len(mb.findall("pointmass"))
    for name in BALLAST:
        mb.append(_ballast(name))
    tree.write(path, encoding="utf-8", xml_declaration=True)
    return Anatomy(
        tuple(f.get("name", "?") for f in control), tuple(f.get("name", "?") for f in damping), n, _span_ft(root)
    )


def refusals(xml_path: str | Path, surface: str) -> dict[str, str]:
    """Why a fault kind cannot fly on this model ({kind: reason}), from its XML; empty if every kind can."""
    a = anatomy(xml_path, surface)
    why = {}
    if not a.effectiveness:
        why["effectiveness"] = f"no aerodynamic coefficient of the model reads the {surface}'s position"
    if not a.damping:
        why["damping"] = "no roll-axis coefficient of the model reads the roll rate (velocities/p-aero-rad_sec)"
    if not a.span_ft:
        for kind in ("inertia", "cg"):
            why[kind] = "the model gives no wing span (metrics/wingspan) for the wing-tip ballast"
    return why
