"""The sign conventions of predict and grid agree: a point source predicted off the phase
centre grids into a uv cube whose phase pattern is exp(-2 pi i (u l0 + v m0)) with the
source's own (l0, m0) (l towards East), and not its mirror image."""

from __future__ import annotations

import numpy as np
import pytest

from msleak.adapters.skymodel import write_skymodel
from msleak.verbs.predict import predict
import msleak
from msleak.sky import PointSources


@pytest.mark.parametrize("offset_deg", [(0.8, 0.3), (-0.5, -0.9)])
def test_predicted_source_grids_at_its_own_position(make_ms, tmp_path, offset_deg):
    ms = make_ms("chain.ms", stations="CS00[1-7]HBA*", duration=4.0, interval=900.0,
                 nchan=2)
    ra0, dec0 = np.radians(123.4), np.radians(48.2)
    # a source offset by (dl, dm) in the tangent plane: l East, m North
    dl, dm = np.radians(offset_deg)
    dec = np.arcsin(dm * np.cos(dec0) + np.sqrt(1 - dl**2 - dm**2) * np.sin(dec0))
    ra = ra0 + np.arctan2(dl, np.sqrt(1 - dl**2 - dm**2) * np.cos(dec0) - dm * np.sin(dec0))
    src = PointSources.parametric([ra], [dec], 1.0, ref_freq=150e6)
    l0, m0, _ = src.lmn(ra0, dec0)
    np.testing.assert_allclose([l0[0], m0[0]], [dl, dm], atol=1e-12)
    sky = write_skymodel(tmp_path / "one.skymodel", src)
    predict(ms, sky, beam="none", column="MODEL_DATA", progress=False)
    cube = msleak.grid(ms, column="MODEL_DATA", cell=16.0, uv_range=(30.0, 180.0))
    vis = cube["vis"].sel(stokes="I").isel(freq=0).values
    weight = cube["weight"].isel(freq=0).values
    u = cube["u"].values[None, :]
    v = cube["v"].values[:, None]
    used = weight > 0
    assert used.sum() > 100
    model = np.exp(-2j * np.pi * (u * l0[0] + v * m0[0]))
    coherence = np.sum(vis[used] * np.conj(model[used])) / np.sum(np.abs(vis[used]))
    mirror = np.sum(vis[used] * model[used]) / np.sum(np.abs(vis[used]))
    assert abs(coherence) > 0.85 and abs(np.angle(coherence)) < 0.05
    assert abs(mirror) < 0.3
