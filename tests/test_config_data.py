import numpy as np
import pytest

from ns2codegen.config import Config, ConfigError, c_identifier
from ns2codegen.data.analytic import downwash_dataset, scenario_mixes
from ns2codegen.data.dataset import Dataset, DatasetError, split_by_pieces


def test_paper_dimensions_and_types(cfg):
    assert cfg.robot_types == ["small", "large"]
    assert cfg.neighbor_types == ["small", "large", "env"]
    assert cfg.phi_dims() == [6, 25, 40, 40, 20]
    assert cfg.rho_dims() == [20, 40, 40, 40, 1]
    assert cfg.with_overrides(layers=3).phi_dims() == [6, 25, 40, 20]
    assert cfg.with_overrides(layers=5, hidden=40).rho_dims() == [40, 40, 40, 40, 40, 1]
    assert cfg.vehicle("small")["mass_g"] == 34.0 and cfg.vehicle("large")["mass_g"] == 67.0


def test_twelve_scenarios_of_table_data_collection(cfg):
    names = [n for _, _, n in scenario_mixes(cfg)]
    assert names == ["S", "S->S", "L->S", "{S,S}->S", "{S,L}->S", "{L,L}->S",
                     "L", "S->L", "L->L", "{S,S}->L", "{S,L}->L", "{L,L}->L"]


def test_identifier_sanitizing():
    assert c_identifier("heavy-lifter 2") == "heavy_lifter_2"
    assert c_identifier("3rd") == "t_3rd"
    assert c_identifier("float") == "float_"
    with pytest.raises(ConfigError):
        c_identifier("---")


def test_bad_configs_are_rejected(cfg):
    raw = cfg.raw
    bad = dict(raw, robot_types=raw["robot_types"] + [dict(raw["robot_types"][0], name="Small")])
    with pytest.raises(ConfigError, match="collide"):
        Config.from_dict(bad)
    bad = dict(raw, interaction_volume={"default": {"lo": [-5, -0.4, -0.4], "hi": [0.4, 0.4, 1.2]}})
    with pytest.raises(ConfigError, match="pos_box"):
        Config.from_dict(bad)
    bad = dict(raw, model=dict(raw["model"], max_neighbors=0))
    with pytest.raises(ConfigError):
        Config.from_dict(bad)


def test_dataset_roundtrip_hash_and_split(cfg, tmp_path):
    ds = downwash_dataset(cfg, 500, seed=3)
    assert len(ds) == 12 * 500 and np.var(ds.label_g) > 10.0
    p = tmp_path / "d.npz"
    ds.save(p)
    back = Dataset.load(p)
    assert back.content_hash() == ds.content_hash()
    assert downwash_dataset(cfg, 500, seed=4).content_hash() != ds.content_hash()
    val = split_by_pieces(ds, 50, 0.2, seed=0)
    assert abs(val.mean() - 0.2) < 0.02
    for s in range(12):  # 10 of 50 contiguous, equal pieces per scenario are held out
        idx = np.flatnonzero(ds.scenario == s)
        idx = idx[np.argsort(ds.time_s[idx], kind="stable")]
        v = val[idx].astype(int)
        assert v.sum() == 100  # 500 samples: 10 pieces of 10
        assert (np.abs(np.diff(v)) == 1).sum() <= 20  # at most 10 held-out runs
    assert np.array_equal(val, split_by_pieces(ds, 50, 0.2, seed=0))
    assert not np.array_equal(val, split_by_pieces(ds, 50, 0.2, seed=1))


def test_dataset_errors(cfg, tmp_path):
    p = tmp_path / "bad.npz"
    p.write_bytes(b"not a zip")
    with pytest.raises(DatasetError):
        Dataset.load(p)
    ds = downwash_dataset(cfg, 10, seed=0)
    ds.nbr_type[-1] = 0  # the environment row must be last
    with pytest.raises(DatasetError, match="environment"):
        ds.validated()


def test_analytic_generators_refuse_a_history_config(cfg):
    """The analytic generators draw single instants: a config with model.history_ms is
    refused in one line naming the field (`ns2 sim collect` and the logs make lagged rows)."""
    from ns2codegen.config import ConfigError
    from ns2codegen.data.analytic import downwash_dataset, max_dataset

    hcfg = cfg.with_overrides(history_ms=[50])
    for make in (downwash_dataset, max_dataset):
        with pytest.raises(ConfigError, match=r"^model.history_ms \[50\]: the .* generator draws single instants"):
            make(hcfg, 10, seed=0)
