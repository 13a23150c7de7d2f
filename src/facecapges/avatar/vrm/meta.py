"""VRM meta: who made the model, its version and its licence, VRM 1.0 (``VRMC_vrm.meta``) and 0.x (``VRM.meta``)."""

from __future__ import annotations

LICENSE_URL = "https://vrm.dev/licenses/1.0/"
SPEC_VERSION = "1.0"  # the VRMC_vrm specVersion written (the meta it carries is VRM 1.0's)


def vrm_meta(name: str = "FaceCapGes avatar", version: str = "0.1.0") -> dict:
    """``VRMC_vrm.meta`` of the avatar we build (its licence: VRM Public Licence 1.0, liberal)."""
    return {
        "name": name,
        "version": version,
        "authors": ["FaceCapGes"],
        "copyrightInformation": "FaceCapGes contributors (MIT licence)",
        "licenseUrl": LICENSE_URL,
        "avatarPermission": "everyone",
        "allowExcessivelyViolentUsage": False,
        "allowExcessivelySexualUsage": False,
        "commercialUsage": "corporation",
        "allowPoliticalOrReligiousUsage": False,
        "allowAntisocialOrHateUsage": False,
        "creditNotation": "unnecessary",
        "allowRedistribution": True,
        "modification": "allowModificationRedistribution",
        "thirdPartyLicenses": "Face mesh: MediaPipe canonical face model (Google), Apache License 2.0.",
    }


def vrm0_meta(meta: dict) -> dict:
    """The VRM 0.x ``VRM.meta`` of our avatar, from its VRM 1.0 ``meta`` (:func:`vrm_meta`)."""
    return {
        "title": meta["name"],
        "version": meta["version"],
        "author": meta["authors"][0],
        "contactInformation": "",
        "reference": "",
        "allowedUserName": "Everyone",
        "violentUssageName": "Disallow",
        "sexualUssageName": "Disallow",
        "commercialUssageName": "Allow",
        "otherPermissionUrl": "",
        # a named licence that allows editing: "Other" (or an other-licence URL) makes importers
        # such as Blender's VRM add-on ask for a licence confirmation before they load the file
        "licenseName": "CC_BY",
        "otherLicenseUrl": "",
    }
