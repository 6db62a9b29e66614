"""Where an episode's network comes from: a fixed network, a reproducible pool or the generator.

:func:`draw_network` is what the environments' one network hook,
:meth:`pipe_env.envs.env.DecisionEnv._gen_network` (MiniGrid's ``_gen_grid``), calls; a subclass
overrides that hook to supply networks another way.

| config | each episode's network |
|---|---|
| ``network`` given | that network |
| ``network_pool=N`` | network ``i`` (drawn) of the pool: seeded by ``(pool_seed, i)`` |
| otherwise | a new network from ``network_config`` and the env's generator |
"""

from __future__ import annotations

import numpy as np

from pipe_env.envs.config import EnvConfig
from pipe_env.generator import NetworkConfig, generate_network
from pipe_env.network import PipeNetwork

#: Pool networks generated in this process, shared by its environments (an evaluation builds
#: several envs on the same pool): (config, pool_seed, index) -> network.
_POOL_CACHE: dict[tuple[str, int, int], PipeNetwork] = {}
_POOL_CACHE_SIZE = 4096


def pool_network(config: NetworkConfig, pool_seed: int, index: int) -> PipeNetwork:
    """Network ``index`` of the pool ``pool_seed`` (the same for every process and run)."""
    key = (repr(config), int(pool_seed), int(index))
    net = _POOL_CACHE.get(key)
    if net is None:
        net = generate_network(config, np.random.default_rng([pool_seed, index]))
        if len(_POOL_CACHE) >= _POOL_CACHE_SIZE:
            _POOL_CACHE.pop(next(iter(_POOL_CACHE)))
        _POOL_CACHE[key] = net
    return net


def draw_network(config: EnvConfig, rng: np.random.Generator) -> PipeNetwork:
    """The next episode's network (see the module docstring); ``rng``: the env's generator."""
    if config.fixed_network is not None:
        return config.fixed_network
    if config.network_pool is None:
        return generate_network(config.generator, rng)
    i = int(rng.integers(config.network_pool))
    return pool_network(config.generator, config.pool_seed, i)
