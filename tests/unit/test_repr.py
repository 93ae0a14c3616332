"""repr() of State and Terrain: one short line whatever the size (the dataclass repr printed
every array: 39,454 characters for a state of 360 elements)."""
import numpy as np
import pytest

from geodem.core.state import BONDED, array_summary, enable_rotation, new_state
from geodem.geo.raster import Terrain
from geodem.geo.terrain import Below


def _state(n, width=12, seed=0):
    rng = np.random.default_rng(seed)
    st = new_state(rng.random((n, 3)) * [10.0, 4.0, 2.0] + [100.0, 0.0, -1.0], 0.05, 1.0,
                   width=width)
    st.groups = {"all": 0, "sample": 1, "base": 2}
    # contacts are stored in both elements' rows: 0-1 bonded, 2-3 a plain contact
    for a, b, code in ((0, 1, BONDED), (2, 3, 0)):
        st.nbr[a, 0], st.nbr[b, 0] = b, a
        st.cstate[a, 0] = st.cstate[b, 0] = code
    return st


def test_state_repr_is_short_and_names_the_counts():
    st = _state(400)
    text = repr(st)
    assert len(text) < 500 and "\n" not in text
    assert text.startswith("State(dim=3, n=400, width=12, contacts=2, bonds=1, box=[")
    lo, hi = st.x.min(axis=0), st.x.max(axis=0)
    assert f"{lo[0]:.4g}..{hi[0]:.4g}" in text and f"{lo[2]:.4g}..{hi[2]:.4g}" in text
    assert "groups=[all, sample, base]" in text and "step=0, time=0 s" in text
    assert "x,v,a,dx,x_ref,free,fload (400, 3) f8" in text
    assert "nbr,cstate (400, 12) i4" in text and "fs (400, 12, 3) f8" in text
    assert "brate (400, 12) f4" in text and "props (400, 8) f8" in text
    assert str(st) == text


def test_state_repr_stays_short_for_any_size():
    st = _state(50_000, width=32)
    st.groups = {f"layer_{k:03d}": k for k in range(200)}
    enable_rotation(st)
    text = repr(st)
    assert len(text) < 500
    assert "n=50000" in text and "width=32" in text and "rotation" in text
    assert "groups=[layer_000, layer_001," in text and "...]" in text  # 200 names clipped
    assert "(50000, 32, 3) f8" in text  # fs and the rolling moments mr


def test_array_summary_groups_by_shape_and_dtype():
    arrays = {"a": np.zeros((5, 2)), "b": np.zeros(5, np.int32), "c": np.ones((5, 2)),
              "d": None}
    assert array_summary(arrays) == "a,c (5, 2) f8; b (5,) i4"
    long = {f"name{k}": np.zeros(k + 1) for k in range(100)}
    out = array_summary(long, limit=120)
    assert len(out) == 120 and out.endswith("...") and out.startswith("name0 (1,) f8; ")


def test_terrain_repr_is_short():
    z = np.add.outer(np.linspace(520.0, 400.0, 300), np.linspace(0.0, 5.0, 400))
    t = Terrain.from_array(z, 2.5, west=650000.0, south=5120000.0, crs="EPSG:32632")
    t.source = "/data/" + "a_very_long_folder_name/" * 20 + "dem_2m.tif"
    text = repr(t)
    assert len(text) < 500 and "\n" not in text
    assert text.startswith("Terrain(z (300, 400) f8 400..525 m, cells 2.5 x 2.5 m, EPSG:32632, "
                           "extent x 0..1000, y 0..750 m, origin (650000, 5120000, 0), ")
    assert text.endswith("folder_name/dem_2m.tif')") and "source '..." in text
    assert repr(Below(t)).startswith("Below(Terrain(z (300, 400) f8")


def test_terrain_repr_without_epsg_names_the_crs():
    wkt = ('PROJCRS["Local mine grid",BASEGEOGCRS["WGS 84",DATUM["World Geodetic System 1984",'
           'ELLIPSOID["WGS 84",6378137,298.257223563]]],CONVERSION["local",METHOD["Transverse '
           'Mercator"]],CS[Cartesian,2],AXIS["easting",east],AXIS["northing",north],'
           'LENGTHUNIT["metre",1]]')
    t = Terrain(z=np.zeros((4, 5)), transform=(1.0, 0.0, 0.0, 0.0, -1.0, 4.0), crs=wkt,
                nodata_filled=3, edge_filled=2)
    text = repr(t)
    assert "Local mine grid" in text and "PROJCRS" not in text
    assert "filled 3 nodata + 2 edge" in text
    assert "no CRS" in repr(Terrain(z=np.zeros((2, 2)), transform=(1, 0, 0, 0, -1, 2)))


@pytest.mark.parametrize("broken", ["nbr", "x"])
def test_repr_of_a_broken_state_does_not_raise(broken):
    st = _state(10)
    setattr(st, broken, None)
    assert repr(st).startswith("State(")


def _hill(crs="EPSG:32632"):
    z = np.add.outer(np.linspace(30.0, 20.0, 20), np.linspace(0.0, 2.0, 40))
    return Terrain.from_array(z, 2.0, west=650000.0, south=5120000.0, crs=crs)


def test_terrain_model_repr_is_short_and_names_the_counts():
    from geodem.geo.terrain import Depth, terrain_model

    m = terrain_model(_hill(), 1.0, base_depth=4.0, layers=[("soil", Depth(3.0))],
                      sliding_surface=Depth(2.0), extent=(4.0, 6.0, 60.0, 34.0))
    text = repr(m)
    assert m.n > 5000 and len(text) < 600 and "\n" not in text
    assert text.startswith(f"TerrainModel(dim=3, n={m.n}, d=1 m, layers [soil ")
    soil = int((m.layer == m.names.index("soil")).sum())
    body = int((m.layer == m.names.index("rock")).sum())
    assert soil + body == m.n and f"layers [soil {soil}, rock {body}]" in text
    assert f"slide {int(m.masks['slide'].sum())}" in text
    assert f"base {int(m.masks['base'].sum())}" in text
    assert "extent x 4..60, y 6..34 m" in text and f"base_z {m.base_z:.6g} m" in text
    assert "EPSG:32632" in text and f"x ({m.n}, 3) f8" in text
    assert str(m) == text


def test_terrain_model_repr_of_a_section_names_its_line():
    from geodem.geo.terrain import terrain_model

    m = terrain_model(_hill(crs=None), 1.0, base_z=15.0, dim=2, line=((5.0, 20.0), (70.0, 20.0)))
    text = repr(m)
    assert text.startswith(f"TerrainModel(dim=2, n={m.n}, d=1 m, layers [rock {m.n}]")
    assert "section 0..65 m along (5, 20)-(70, 20)" in text and "no CRS" in text
    assert f"x ({m.n}, 2) f8" in text and "base_z 15 m" in text


def test_terrain_model_repr_does_not_raise_when_broken():
    from geodem.geo.terrain import terrain_model

    m = terrain_model(_hill(), 2.0, base_depth=4.0)
    m.extent = None
    assert repr(m) == "TerrainModel(<unprintable: TypeError>)"
