"""What each named parameter is, and its SI unit (tables, reports, history).

Units are written without ambiguity: ``N·A⁻¹`` for a force/current factor,
never ``N/A`` (which reads as "not applicable").

Examples
--------
>>> parameter_unit("ki1")
'N·A⁻¹'
>>> parameter_unit("unknown") is None
True
"""

from __future__ import annotations

__all__ = ["PARAMETER_INFO", "UNIT_WORDS", "parameter_unit"]

#: ``name -> (what it is, SI unit)`` for the AMB's physical parameters and v1..v9.
PARAMETER_INFO: dict[str, tuple[str, str]] = {
    "m": ("rotor mass", "kg"),
    "i0": ("bias current", "A"),
    "x0": ("air gap", "m"),
    "R1": ("coil 1 resistance", "Ω"),
    "R2": ("coil 2 resistance", "Ω"),
    "Ls1": ("coil 1 leakage inductance", "H"),
    "Ls2": ("coil 2 leakage inductance", "H"),
    "Lo1": ("coil 1 air-gap inductance", "H"),
    "Lo2": ("coil 2 air-gap inductance", "H"),
    "L1": ("coil 1 inductance", "H"),
    "L2": ("coil 2 inductance", "H"),
    "K1": ("coil 1 constant N²Aμ0", "H·m"),
    "K2": ("coil 2 constant N²Aμ0", "H·m"),
    "ki1": ("coil 1 force/current factor", "N·A⁻¹"),
    "ki2": ("coil 2 force/current factor", "N·A⁻¹"),
    "ks1": ("coil 1 force/displacement factor", "N·m⁻¹"),
    "ks2": ("coil 2 force/displacement factor", "N·m⁻¹"),
    "ks_sum": ("total force/displacement factor", "N·m⁻¹"),
    "kw1": ("amplifier 1 gain", "V·V⁻¹"),
    "kw2": ("amplifier 2 gain", "V·V⁻¹"),
    "v1": ("(ks1 + ks2)/m", "s⁻²"),
    "v2": ("ki1/m", "m·s⁻²·A⁻¹"),
    "v3": ("ki2/m", "m·s⁻²·A⁻¹"),
    "v4": ("ki1/L1", "A·m⁻¹"),
    "v5": ("R1/L1", "s⁻¹"),
    "v6": ("ki2/L2", "A·m⁻¹"),
    "v7": ("R2/L2", "s⁻¹"),
    "v8": ("kw1/L1", "A·V⁻¹·s⁻¹"),
    "v9": ("kw2/L2", "A·V⁻¹·s⁻¹"),
}


#: Each unit in words (tooltips of the report).
UNIT_WORDS: dict[str, str] = {
    "kg": "kilogram",
    "A": "ampere",
    "m": "metre",
    "Ω": "ohm",
    "H": "henry",
    "H·m": "henry metre",
    "N·A⁻¹": "newton per ampere",
    "N·m⁻¹": "newton per metre",
    "V·V⁻¹": "volt per volt (a gain)",
    "s⁻²": "per second squared",
    "m·s⁻²·A⁻¹": "metre per second squared per ampere",
    "A·m⁻¹": "ampere per metre",
    "s⁻¹": "per second",
    "A·V⁻¹·s⁻¹": "ampere per volt per second",
}


def parameter_unit(name: str) -> str | None:
    """SI unit of a named parameter, or ``None`` when maglevid does not know it."""
    info = PARAMETER_INFO.get(name)
    return None if info is None else info[1]
