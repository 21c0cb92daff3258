"""A set-up `wild-thermal` trainer on the demo scene, for the tests that train through nerfstudio."""

from thermal_wild_ns.demo import demo_trainer_config


def demo_trainer(out, scene_dir, steps: int, section: str, **settings):
    """The demo config (at most 3,000 Gaussians) trained for `steps` steps, with `settings` set on its
    `section` (e.g. 'guard', 'auto_stop'); set up, not trained."""
    config = demo_trainer_config(out, steps=steps, max_gaussians=3000)
    config.pipeline.datamanager.dataparser.data = scene_dir
    for key, value in settings.items():
        setattr(getattr(config, section), key, value)
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    return trainer
