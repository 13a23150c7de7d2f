"""VRM meta: who made the model, its version and its licence, VRM 1.0 (``VRMC_vrm.meta``) and 0.x (``VRM.meta``)."""

from __future__ import annotations

LICENSE_URL = "https://vrm.dev/licenses/1.0/"
# The one licence both files state. VRM 0.x names it (licenseName CC_BY; a named, editable licence, so
# importers such as Blender's VRM add-on load it without asking). VRM 1.0 has no licence name: its meta
# always carries the VRM Public License 1.0 (the schema's only licenseUrl) with parameters, set here to
# CC BY's terms (credit required; any use, modification and redistribution allowed), and says CC BY 4.0 in
# its copyright information.
LICENCE = "CC BY 4.0"
VRM0_LICENSE_NAME = "CC_BY"
SPEC_VERSION = "1.0"  # the VRMC_vrm specVersion written (the meta it carries is VRM 1.0's)


def vrm_meta(name: str = "FaceCapGes avatar", version: str = "0.1.0") -> dict:
    """``VRMC_vrm.meta`` of the avatar we build (its licence: :data:`LICENCE`, as the VRM Public License's terms)."""
    return {
        "name": name,
        "version": version,
        "authors": ["FaceCapGes"],
        "copyrightInformation": f"FaceCapGes contributors; licence {LICENCE} (credit FaceCapGes)",
        "licenseUrl": LICENSE_URL,
        "avatarPermission": "everyone",
        "allowExcessivelyViolentUsage": False,
        "allowExcessivelySexualUsage": False,
        "commercialUsage": "corporation",
        "allowPoliticalOrReligiousUsage": False,
        "allowAntisocialOrHateUsage": False,
        "creditNotation": "required",
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
        "licenseName": VRM0_LICENSE_NAME,
        "otherLicenseUrl": "",
    }
