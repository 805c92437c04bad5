"""Stripe-based object matching (the stripes paper): extraction, descriptor, matching, database.

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``).
An object is an ordered list of stripes (2D point paths, one per laser line); each
stripe becomes ``[l, d, o]`` (Eq. 1-3, `descriptor`); two objects are compared by the
Bhattacharyya distances of Gaussian fits of each feature after trimming (Eq. 4-6,
`matching`); `database.StripeDatabase` answers a query against thousands of objects in
one vectorised pass.  `profile` keeps the stripes in scan order instead: a fixed-length,
scale-free sequence of ``[l, d, e]`` per object (`profile.ProfileDatabase`), for object
classes whose members differ in size; `relief` reads the stripes' heights as one top
view (how far the surface lies below the object's top, ring by ring about its centre:
`relief.ReliefDatabase`); `surface` takes Eq. 1-2's pair distances and directions over
the whole object's 3D surface (`surface.SurfaceDatabase`); `canonical` cuts the same
heights into virtual stripes along the footprint's long axis, free of the scan
direction (`canonical.CanonicalDatabase`); `fusion.FusedObjectDatabase` fuses profile,
relief, surface context (and the canonical profile) with silhouette matchers, each
part locally scaled (`fusion.local_scaled`).
"""

from loopclosure.stripes.canonical import (
    CanonicalConfig,
    CanonicalDatabase,
    CanonicalProfile,
    describe_canonical,
)
from loopclosure.stripes.database import StripeDatabase
from loopclosure.stripes.descriptor import (
    DescriptorConfig,
    StripeDescriptor,
    describe_many,
    describe_stripes,
    resample_stripes,
)
from loopclosure.stripes.extraction import (
    chain_pixels,
    stripe_from_binary_image,
    stripe_from_laser_image,
    stripes_from_laser_images,
    stripes_from_points,
    thin,
)
from loopclosure.stripes.fusion import (
    DEFAULT_MEAN,
    DEFAULT_SCALING,
    DEFAULT_VERIFIERS,
    FAST_VERIFIERS,
    FUSED_DESCRIPTOR,
    LOCAL_NEIGHBOUR,
    MEANS,
    SC_VERIFIERS,
    SCALINGS,
    FusedObjectDatabase,
    combine,
    database_scales,
    fuse,
    local_scaled,
    neighbour_scale,
    normalised,
)
from loopclosure.stripes.matching import (
    LAMBDA_PAPER,
    bhattacharyya,
    feature_distances,
    search_weights,
    stratified_split,
    stripe_distance,
    trim_range,
)
from loopclosure.stripes.profile import (
    PROFILE_SAMPLES,
    ProfileConfig,
    ProfileDatabase,
    StripeProfile,
    describe_profile,
    describe_profiles,
    resample_profile,
    stripe_shape,
)
from loopclosure.stripes.relief import (
    ReliefConfig,
    ReliefDatabase,
    StripeRelief,
    describe_relief,
)
from loopclosure.stripes.surface import (
    StripeSurface,
    SurfaceConfig,
    SurfaceDatabase,
    describe_surface,
    surface_histogram,
    surface_points,
)

__all__ = [
    "DEFAULT_MEAN",
    "DEFAULT_SCALING",
    "DEFAULT_VERIFIERS",
    "FAST_VERIFIERS",
    "FUSED_DESCRIPTOR",
    "LAMBDA_PAPER",
    "LOCAL_NEIGHBOUR",
    "MEANS",
    "PROFILE_SAMPLES",
    "SCALINGS",
    "SC_VERIFIERS",
    "CanonicalConfig",
    "CanonicalDatabase",
    "CanonicalProfile",
    "DescriptorConfig",
    "FusedObjectDatabase",
    "ProfileConfig",
    "ProfileDatabase",
    "ReliefConfig",
    "ReliefDatabase",
    "StripeDatabase",
    "StripeDescriptor",
    "StripeProfile",
    "StripeRelief",
    "StripeSurface",
    "SurfaceConfig",
    "SurfaceDatabase",
    "bhattacharyya",
    "chain_pixels",
    "combine",
    "database_scales",
    "describe_canonical",
    "describe_many",
    "describe_profile",
    "describe_profiles",
    "describe_relief",
    "describe_stripes",
    "describe_surface",
    "feature_distances",
    "fuse",
    "local_scaled",
    "neighbour_scale",
    "normalised",
    "resample_profile",
    "resample_stripes",
    "search_weights",
    "stratified_split",
    "stripe_distance",
    "stripe_from_binary_image",
    "stripe_from_laser_image",
    "stripe_shape",
    "stripes_from_laser_images",
    "stripes_from_points",
    "surface_histogram",
    "surface_points",
    "thin",
    "trim_range",
]
