"""The Fig. 18 study and the resolution check against the imaging module's migration."""

from __future__ import annotations

import numpy as np

from fusion_center.topology import NetworkGeometry
from uwbnet.topology_study import BAND, linear_track, psf_check, receivers, resolution_study


def test_predicted_resolution_matches_the_kirchhoff_migration_psf():
    net = NetworkGeometry(transmitters=linear_track(21), receivers=receivers(1.0))
    out = psf_check(net, BAND, np.array([5.0, 7.0]))
    # The issue asks for 20 %; the coherent migration of band-limited echoes is the AF.
    assert np.all(np.abs(out["relative_error"]) < 0.05), out
    assert out["predicted_widths_m"][0] > out["predicted_widths_m"][1]


def test_broadside_track_resolves_along_its_rotation():
    out = resolution_study()
    b, r = out["broadside"], out["radial"]
    assert b["rotation_deg"] > 4 * r["rotation_deg"]
    one = b["single_frequency"]
    assert one["width_x_m"] < 0.5 * one["width_y_m"]  # rotation is along x
    assert one["width_x_m"] < r["single_frequency"]["width_x_m"]
