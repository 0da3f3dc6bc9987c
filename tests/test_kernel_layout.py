"""The plant kernel's parameter vector is declared once (`plant_params.KERNEL_LAYOUT`).

The kernels read exactly that layout: the constants tuple carries every slot the table marks,
divided by the inertia the table names, in the table's order; the longer tuple of a model with
discovered terms carries every number of every term slot (a wider monomial, from a new
primitive, widens the slots and the tuple with it); the kernel's factors are the numpy ones
of `flaair_model.terms.primitive_values`, primitive by primitive; and every effect-table kernel
term has its place in the table.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from flaair_model.effects import PLANT_TERMS, SCALE_TERMS, SENSOR_TERMS
from flaair_model.terms import MAX_DYNAMICS_TERMS, PRIMITIVES, primitive_values
from flaair_sim.core import plant_kernel, term_kernel
from flaair_sim.core import plant_params as pp

RNG_SEED = 35


def _vector() -> np.ndarray:
    """A parameter vector with a distinct number in every place (inertias away from zero)."""
    return np.random.default_rng(RNG_SEED).uniform(0.5, 2.0, pp.N_KERNEL_PARAMS)


def test_the_vector_is_the_table_then_the_term_slots() -> None:
    assert len(pp.KERNEL_LAYOUT) == pp.P_TERMS
    assert pp.P_NTERMS == pp.P_TERMS - 1
    assert 3 + len(PRIMITIVES) == pp.TERM_SLOT and pp.TERM_LOWPASS == pp.TERM_SLOT - 1
    assert pp.N_KERNEL_PARAMS == pp.P_TERMS + MAX_DYNAMICS_TERMS * pp.TERM_SLOT
    for slot in pp.KERNEL_LAYOUT:
        assert getattr(pp, f"P_{slot.name}") == pp.KERNEL_LAYOUT.index(slot)
    assert (pp.GA_INDEX, pp.CONTACT_ON_INDEX) == (pp.P_GA, pp.P_CONTACT_ON)


def test_every_effect_kernel_term_has_its_place_and_no_other_term_does() -> None:
    named = {slot.term for slot in pp.KERNEL_LAYOUT} - {None}
    assert named == set(PLANT_TERMS + SCALE_TERMS + SENSOR_TERMS)
    for term in SENSOR_TERMS:
        chains = sorted(s.chain for s in pp.KERNEL_LAYOUT if s.term == term)
        assert chains == [0, 1], term


@pytest.mark.timeout(120)
def test_the_constants_tuple_is_the_marked_slots_over_their_inertia() -> None:
    p = _vector()
    c = term_kernel.mechanical_constants(p)
    marked = [(i, s) for i, s in enumerate(pp.KERNEL_LAYOUT) if s.constant]
    assert len(c) == pp.N_CONSTANTS == len(marked) == 12
    over = {"as_is": 1.0, "over_stroke_inertia": p[pp.P_I], "over_pitch_inertia": p[pp.P_IP]}
    for j, (i, slot) in enumerate(marked):
        assert c[j] == pytest.approx(p[i] / over[slot.constant], rel=1e-15), slot.name
        assert getattr(pp, f"C_{slot.name}") == j


@pytest.mark.timeout(120)
def test_the_longer_tuple_carries_every_number_of_every_term_slot() -> None:
    p = _vector()
    for slot, places in enumerate([(0, 3, 5, 12, 15), (1, 2, 4, 6, 7, 9, 10, 13, 14)]):
        exponents = np.zeros(len(PRIMITIVES))
        exponents[list(places)] = 1 + np.arange(len(places)) % 3
        start = pp.P_TERMS + slot * pp.TERM_SLOT + 2
        p[start : start + len(PRIMITIVES)] = exponents
    c = term_kernel.constants_with_terms(p)
    assert len(c) == pp.N_CONSTANTS_WITH_TERMS == pp.N_CONSTANTS + MAX_DYNAMICS_TERMS
    assert c[: pp.N_CONSTANTS] == term_kernel.mechanical_constants(p)
    for slot, place in enumerate(pp.C_TERM_SLOTS):  # each slot: its fields, factors packed
        src = pp.P_TERMS + slot * pp.TERM_SLOT
        fields = dict(zip(term_kernel.SLOT_FIELDS, c[place], strict=True))
        assert (fields["equation"], fields["coefficient"]) == tuple(p[src : src + 2])
        assert fields["corner_rad_s"] == p[src + pp.TERM_LOWPASS]
        exponents = p[src + 2 : src + pp.TERM_LOWPASS]
        factors = [(j, int(e)) for j, e in enumerate(exponents) if e]
        assert factors, "the vector's slots all carry a monomial"
        assert _unpacked(fields["factors_a"]) + _unpacked(fields["factors_b"]) == factors


def _unpacked(code: float) -> list[tuple[int, int]]:
    """The (primitive, power) pairs packed in a factors code, read with Python's integers."""
    number = int(code)
    assert number == code, "a code is an exact integer"
    pairs = []
    while number:
        number, factor = divmod(number, 2**term_kernel.FACTOR_BITS)
        pairs.append(divmod(factor, 2**term_kernel.POWER_BITS))
    return pairs


@pytest.mark.timeout(120)
@pytest.mark.parametrize("j", range(len(PRIMITIVES)))
def test_each_kernel_factor_is_the_numpy_one(j: int) -> None:
    grid = np.array(list(itertools.product((-0.3, 0.0, 0.7), repeat=7))).T  # states, v, t, dv
    numpy_factors = primitive_values(*grid)
    assert len(numpy_factors) == len(PRIMITIVES)
    kernel = [term_kernel.primitive(j, *state) for state in grid.T]
    np.testing.assert_array_equal(kernel, numpy_factors[j], err_msg=PRIMITIVES[j])


@pytest.mark.timeout(120)
@pytest.mark.parametrize("first", [0, len(PRIMITIVES) - pp.MAX_FACTORS])
def test_a_term_slot_evaluates_its_whole_monomial_in_the_kernel(first: int) -> None:
    p = np.zeros(pp.N_KERNEL_PARAMS)
    exponents = np.zeros(len(PRIMITIVES))  # MAX_FACTORS primitives, powers 1, 2, 3, 1, ...
    exponents[first : first + pp.MAX_FACTORS] = 1 + np.arange(pp.MAX_FACTORS) % 3
    base = pp.P_TERMS
    p[pp.P_I] = p[pp.P_IP] = 1.0
    p[pp.P_NTERMS] = 1.0
    p[base], p[base + 1] = 1.0, 0.25
    p[base + 2 : base + pp.TERM_LOWPASS] = exponents
    state = (0.3, -0.7, 0.4, 1.3, -2.5, 0.8, -40.0)  # the states, the drive, time, drive rate
    c = term_kernel.constants_with_terms(p)
    factors = [term_kernel.primitive(j, *state) for j in range(len(PRIMITIVES))]
    expected = 0.25 * float(np.prod(np.power(factors, exponents)))
    stroke, pitch = term_kernel.dynamics_terms(c, *state, 0.0, 0.0)
    assert stroke == pytest.approx(expected, rel=1e-14)
    assert expected != 0.0
    assert pitch == 0.0


@pytest.mark.timeout(120)
def test_a_low_pass_slot_is_a_first_order_state_integrated_with_the_mechanics() -> None:
    """A slot with a low-pass (corner w rad/s): its state z follows z' = w (x - z) with the RK4
    step, x its monomial; the torque is the coefficient times z. With every plant constant zero
    the stroke stays at phi0, so from z = 0 the state is phi0 (1 - e^(-w t)) and the pitch rate
    the torque's integral, c phi0 (t - (1 - e^(-w t)) / w), both to RK4's accuracy.
    """
    fs, corner, phi0, coef = 20_000.0, 300.0, 0.2, -0.5
    w = 2 * np.pi * corner
    p = np.zeros(pp.N_KERNEL_PARAMS)
    p[pp.P_I] = p[pp.P_IP] = 1.0
    p[pp.P_NTERMS] = 1.0
    base = pp.P_TERMS + pp.TERM_SLOT  # the second slot: each slot has its own state
    p[base], p[base + 1] = 2.0, coef
    p[base + 2 + PRIMITIVES.index("phi")] = 1.0
    p[base + pp.TERM_LOWPASS] = w
    c = term_kernel.constants_with_terms(p)
    held = np.zeros(pp.HELD_LEN)
    x = (phi0, 0.0, 0.0, 0.0)
    n = 200
    for k in range(n):
        x = plant_kernel.rk4_step(*x, 0.0, c, 1.0 / fs, 0, k / fs, 0.0, held, True)[:4]
    t = n / fs
    assert x[0] == phi0
    assert held[pp.HELD_LOWPASS + 1] == pytest.approx(phi0 * (1 - np.exp(-w * t)), rel=1e-9)
    assert x[3] == pytest.approx(coef * phi0 * (t - (1 - np.exp(-w * t)) / w), rel=1e-8)
    assert held[pp.HELD_LOWPASS] == 0.0  # the first slot is empty
