"""Procedural scenes with ground truth, composites and mask noise models.

Everything accuracy is measured on stands on these: a scene made of Gaussians
whose per-Gaussian object labels are known exactly, composites that insert an
object (procedural or read from a file) into another scene and label the
inserted Gaussians, and noise models that corrupt supervision masks the way
a 2D tracker fails.

Scenes (:func:`make_scene`, module :mod:`.scenes`)
    A textured ground plane (label 0) and seven objects (sphere, box, cup
    and its contents, thin rod, two identical cans), each exercising one
    difficulty; see :mod:`seed2gs_inverse.synthetic.scenes` for the table.

Composites (:func:`compose`, :func:`pose_on_point`)
    ``compose(background, [(object_scene, pose), ...])`` moves each object
    with :meth:`GaussianScene.transformed` (SH rotated with it), concatenates
    and labels background Gaussians 0 and the k-th object k.

Masks (:func:`masks_from_labels`, :func:`render_label_masks`, :func:`perturb_masks`)
    Masks are float arrays in [0, 1] of shape ``(H, W)``; NaN marks unknown
    pixels that carry no evidence. Ground-truth masks threshold the rendered
    object weight ``W(c) 1_object``; noise models stand in for tracking
    failures.

Ground scenes (:func:`make_ground_scene`, :func:`place_object`, module :mod:`.ground`)
    A randomly rotated, optionally uneven ground with vertical clutter
    (grass, fence, wall, bushes) and objects resting on it in contact, with
    exact labels and level look-at cameras about the true up: the test bed
    of the orbit axis (:mod:`seed2gs_inverse.pipeline.up_axis`) and of point
    prompts that return whole objects.

The package has one module per job: :mod:`.scenes` (procedural scenes),
:mod:`.ground` (ground scenes), :mod:`.compose` (composites) and
:mod:`.noise` (masks and noise models);
every public name is re-exported here, so ``seed2gs_inverse.synthetic.X``
works for all of them.
"""

from .compose import compose, parse_pose, pose_on_point, surface_point
from .ground import CLUTTER_KINDS, OBJECT_KINDS, GroundScene, make_ground_scene, place_object, random_rotation
from .noise import NOISE_KINDS, masks_from_labels, perturb_masks, render_label_masks
from .scenes import SyntheticScene, make_scene

__all__ = ["SyntheticScene", "make_scene", "compose", "pose_on_point", "parse_pose", "surface_point",
           "masks_from_labels", "render_label_masks", "perturb_masks", "NOISE_KINDS", "GroundScene",
           "make_ground_scene", "place_object", "random_rotation", "OBJECT_KINDS", "CLUTTER_KINDS"]
