"""The private torch, tensordict, TorchRL and Hydra APIs the project relies on
(params/private_api.py) are still there and still do what it needs: each check names the
one an upgrade removed or changed."""

from __future__ import annotations

import inspect

import pytest
import torch
from omegaconf import OmegaConf
from tensordict import TensorDict
from torchrl.envs import EnvBase

from params import private_api


def test_unchecked_tensordicts_hold_their_entries():
    td = private_api.new_tensordict({"a": torch.zeros(3, 2)}, torch.Size([3]))
    assert isinstance(td, TensorDict) and td.batch_size == torch.Size([3]) and td["a"].shape == (3, 2)
    more = private_api.with_entries(td, b=torch.ones(3))
    assert set(more.keys()) == {"a", "b"} and set(td.keys()) == {"a"}  # td unchanged
    private_api.set_entry(td, "c", torch.ones(3))
    assert torch.equal(private_api.get_entry(td, "c"), torch.ones(3))
    assert private_api.get_entry(td, "missing") is None and not private_api.has_names(td)


def test_torchrl_replay_buffer_reads_its_storage_through_the_attribute():
    from learners.member import RowReplayBuffer

    buffer = RowReplayBuffer(8, 3, batch_size=2)
    assert private_api.REPLAY_BUFFER_STORAGE in type(buffer).__dict__  # our property overrides it
    from torchrl.data import ReplayBuffer

    assert f"self.{private_api.REPLAY_BUFFER_STORAGE}" in inspect.getsource(ReplayBuffer.__len__), \
        "TorchRL's ReplayBuffer no longer reads self._storage: RowReplayBuffer's queue would not flush"
    buffer.put(torch.ones(2, 3))
    assert len(buffer) == 2  # the rows put booked through the property
    assert private_api.writer_cursor(buffer) == 2  # the writer's cursor, where the next put writes


def test_torchrl_env_base_has_the_hooks_the_one_pass_step_checks():
    for name in private_api.ENV_BASE_NAMES:
        assert callable(getattr(EnvBase, name, None)), f"torchrl.envs.EnvBase.{name} is gone"
    source = inspect.getsource(EnvBase)
    for name in private_api.ENV_BASE_FLAGS:
        assert name in source, f"torchrl.envs.EnvBase no longer uses {name}"


def test_hydra_basic_sweeper_splits_arguments():
    from hydra.core.override_parser.overrides_parser import OverridesParser

    sweeper = private_api.basic_sweeper()
    overrides = OverridesParser.create().parse_overrides(["a=1,2", "b=3"])
    jobs = [job for batch in sweeper.split_arguments(overrides, None) for job in batch]
    assert jobs == [["a=1", "b=3"], ["a=2", "b=3"]]


def test_hydra_sets_value_overrides_and_names_the_override_dirname():
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    cfg = OmegaConf.create({"a": {"b": 1, "c": [1]}, "hydra": {"job": {"config": {"override_dirname": {
        "kv_sep": "=", "item_sep": ",", "exclude_keys": ["seed"]}}}}})
    OmegaConf.set_struct(cfg, True)
    overrides = OverridesParser.create().parse_overrides(["a.b=2", "a.c=[3,4]", "seed=5"])
    private_api.apply_value_overrides(overrides[:2], cfg)
    assert cfg.a.b == 2 and list(cfg.a.c) == [3, 4]
    assert private_api.overrides_dirname(overrides, cfg) == "a.b=2,a.c=[3,4]"


def test_hydras_sources_read_yaml_with_omegaconf_load_and_a_parse_is_reused_not_shared(tmp_path):
    """``configs_parsed_once``: Hydra's file and package sources read through
    ``OmegaConf.load(<open file>)``; within it, a text read again is a copy of its first parse
    (never the same object), an edited file is read anew, and a file that does not parse
    fails as it does without it."""
    from hydra._internal.core_plugins import file_config_source, importlib_resources_config_source
    from omegaconf import OmegaConf

    from tasks.catalog import compose

    for module in (file_config_source, importlib_resources_config_source):
        assert "OmegaConf.load(f)" in inspect.getsource(module), f"{module.__name__} no longer reads with OmegaConf.load"
    path = tmp_path / "a.yaml"
    path.write_text("a: {b: 1}\n")
    with private_api.configs_parsed_once():
        with open(path) as f:
            first = OmegaConf.load(f)
        first.a.b = 5  # a caller's edit is its own
        with open(path) as f:
            assert OmegaConf.load(f) == {"a": {"b": 1}}
        path.write_text("a: {b: 2}\n")
        with open(path) as f:
            assert OmegaConf.load(f) == {"a": {"b": 2}}
        path.write_text("a: [1\n")
        with open(path) as f, pytest.raises(Exception) as within:
            OmegaConf.load(f)
        assert compose("cartpole", learner="dqn") == compose("cartpole", learner="dqn")
    with open(path) as f, pytest.raises(Exception) as plain:
        OmegaConf.load(f)
    assert str(within.value) == str(plain.value)
    assert not getattr(OmegaConf.load, "parsed_once", False)  # restored on leaving
    assert compose("cartpole", learner="dqn") == compose("cartpole", learner="dqn")


def test_hydras_mode_is_read_from_one_composition_and_the_flag_answers_it_where_no_config_can_set_it():
    """``Hydra.get_mode`` composes the config only to read ``hydra.mode``; within
    ``mode_of_the_flag(True)`` it answers None without composing, unless an override names
    ``hydra.mode`` or ``hydra.searchpath`` (then Hydra's own composition answers), and
    always with ``mode_of_the_flag(False)`` (a config folder beyond conf/)."""
    from hydra._internal.hydra import Hydra

    source = inspect.getsource(Hydra.get_mode)
    assert "self.compose_config(" in source and "cfg.hydra.mode" in source, "Hydra.get_mode changed"
    composed = []

    class Fake:
        def compose_config(self, **kwargs):
            composed.append(kwargs["overrides"])
            return OmegaConf.create({"hydra": {"mode": "MULTIRUN"}})

    with private_api.mode_of_the_flag(True):
        assert Hydra.get_mode(Fake(), "config", ["seed=1"]) is None and composed == []
        assert Hydra.get_mode(Fake(), "config", ["hydra.mode=MULTIRUN"]) == "MULTIRUN"
        assert Hydra.get_mode(Fake(), "config", ["hydra.searchpath=[file:///x]"]) == "MULTIRUN"
    with private_api.mode_of_the_flag(False):
        assert Hydra.get_mode(Fake(), "config", ["seed=1"]) == "MULTIRUN"
    assert len(composed) == 3
    assert Hydra.get_mode(Fake(), "config", ["seed=1"]) == "MULTIRUN"  # Hydra's own again after it
