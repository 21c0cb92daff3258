"""A set-up `wild-thermal` trainer on the demo scene, for the tests that train through nerfstudio."""

from thermal_wild_ns.demo import demo_trainer_config
from thermal_wild_ns.preprocessing.photometric import PhotometricConfig
from thermal_wild_ns.training.trainer import seeded_trainer


def demo_trainer(out, scene_dir, steps: int, section: str, preprocessed: bool = False, **settings):
    """The demo config (at most 3,000 Gaussians) trained for `steps` steps, with `settings` set on its
    `section` (e.g. 'guard', 'auto_stop'); set up, not trained. `preprocessed`: the frames are
    preprocessed whatever the full method's rule decides for the demo (it trains the demo raw)."""
    config = demo_trainer_config(out, steps=steps, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = scene_dir
    if preprocessed:
        config.pipeline.datamanager.preprocessing = PhotometricConfig()
    for key, value in settings.items():
        setattr(getattr(config, section), key, value)
    trainer = seeded_trainer(config)
    return trainer
