"""The bus benchmark's rate column: a measured rate or a dash with the reason, never a
figure made of a clamped denominator."""

from services.tools.bench.bus import rate_text


def test_a_rate_is_measured_or_refused_with_its_reason():
    assert rate_text(1000, 1000, 0.01) == "100,000"
    assert rate_text(900, 1000, 0.01) == "90,000 (900 of 1000 arrived)"
    assert rate_text(0, 1000, 0.0) == "— (none arrived)"
    assert rate_text(5, 5, -1.0).startswith("— (no time measured")
