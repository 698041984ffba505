"""The APR model: GQN encoder and generator, SAC policy heads, and the joint learner.

Importing this package imports torch; the CLI imports it lazily.
"""

from apr.model.agent import APRAgent, FixationBatch, GraspBatch, Observation
from apr.model.config import ModelConfig, gqn_learning_rate, pixel_sigma
from apr.model.encoder import TowerEncoder, encode_scene, images_to_float
from apr.model.generator import ConvDRAWGenerator, gqn_elbo_loss
from apr.model.heads import Actor, Critic, PolicyHeads, TwinCritic
from apr.model.sac import bandit_critic_loss, sac_actor_loss, sac_critic_loss, soft_update, temperature_loss

__all__ = [
    "APRAgent",
    "Actor",
    "ConvDRAWGenerator",
    "Critic",
    "FixationBatch",
    "GraspBatch",
    "ModelConfig",
    "Observation",
    "PolicyHeads",
    "TowerEncoder",
    "TwinCritic",
    "bandit_critic_loss",
    "encode_scene",
    "gqn_elbo_loss",
    "gqn_learning_rate",
    "images_to_float",
    "pixel_sigma",
    "sac_actor_loss",
    "sac_critic_loss",
    "soft_update",
    "temperature_loss",
]
