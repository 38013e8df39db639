"""The engine's settings for one search, as one frozen object (what is searched and what is accepted).

What belongs to the scene (the image, the table pose, located fixtures, known surfaces) is passed to
:func:`app.vision.object_pose.locate_object` beside it; what says *how* to search and *when* to accept
lives here, so that a caller changes one value without restating twenty.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from app.vision.object_pose.search import COARSE_STEP_MAX_MM, SEARCH_THREADS
from app.vision.object_pose.uncertainty import (CONTACT_SIGMA_DEG, CONTACT_SIGMA_MM, FREE_CONTACT_SIGMA_DEG,
                                                HELD_CONTACT_SIGMA_DEG, RISER_SIGMA_MM, SIGMA_SCALE,
                                                STATED_SIGMA_SCALE)


@dataclass(frozen=True)
class LocateOptions:
    """How to search for a part and when to accept it.

    gamma : the camera's encoding gamma (intensities are decoded as ``(I/255) ** gamma``)
    height_offsets_mm : heights above the table to search (mm); an entry may be ``(height, (x0, x1,
        y0, y1))`` to search that height only over part of the table (a fixture's face)
    free_height : fit the height above the table too (parts on risers of unknown height)
    resting_states : indices into ``model.resting_states`` to try (None: the distinct states with a
        probability of at least 0.1, the likeliest and the CAD z-up/z-down stances)
    min_score : least share of visible model edges supported by image edges to accept
    min_verified_score : a best fit under this share is refused as too weak before its rivals,
        contact fit and sigma are worked out, as one under ``min_score`` is; recognition sets its own
        floor here and keeps ``min_score`` at 0, so that a model's readings are chosen as before (a
        turned-over reading replaces the first whatever its score) and only the work on a fit that
        cannot be accepted is saved
    min_margin : least score difference to the best different pose
    min_distinctiveness : least drop of the score when the fitted pose is moved by 4 px along x, y or
        turned as much (fits onto a single straight edge or onto texture do not drop and are refused)
    max_unexplained : largest share of the image's edge pixels inside the fitted outline that the
        model may leave unexplained (a part hides what lies behind it); 1.0 turns the test off
    lines_across : leave the longest straight lines across the outline (a cast shadow) out of that
        share (``verify.on_lines_across``); recognition turns it off: among 20 models it let three
        wrong parts in on the devset (setup_016, 024, 031) and cost 024 its right one
    max_tilt_deg : residual tilt above which (and above 3 sigma) the result carries the "tilt" flag
    max_sigma_mm, max_sigma_deg : tolerances on the 1-sigma uncertainty (``uncertainty_ok``)
    n_starts : search peaks per resting state and height; ``n_planar`` : best of those aligned in the
        table plane; ``n_refine`` : distinct aligned starts refined and verified
    settle_starts : search each start once more densely around itself before the fine fit
    n_coarse : coarse cells of the plane search re-scored in the image (per resting state and height)
    coarse_step_max_mm : the plane search's coarse cell is the part's size / 18, at most this (mm)
    turn_maxima : at least this many local maxima of every turn of the coarse correlation are
        re-scored in the image (``search.local_maxima_per_turn``: 4 to 16 by the table's size)
    self_occlusion : the plane search's image scores leave out the edges the model hides behind
        itself from where the camera sees it (one z-buffer per 15 deg of view, ``search._self_hidden``)
    max_edges : image edge pixels cast onto the search planes (a random subset beyond)
    search_threads : resting states searched at the same time (``search.SEARCH_THREADS``); the
        result does not depend on it
    sigma_scale : factor on the image's share of the covariance in the fit's own decisions (the
        contact prior's weight, a declared riser's match, the tilt flag): deliberately wide
    stated_sigma_scale : that factor in the covariance and sigma the result states (and the gate
        judges): calibrated on held-out scenes
    seed : of the edge subset (results are reproducible)
    contact_sigma_mm, contact_sigma_deg : how far a part on a known surface may sit above it or tilt
        (a chip, a burr, a strap pressing one side); ``riser_sigma_mm`` : the prior on the height
        above a riser of unknown height; ``free_contact_sigma_deg`` : the tilt of a part lying on the
        table itself, held by no jaw face; ``held_contact_sigma_deg`` : the tilt of a part a jaw
        face presses onto its seat
    riser_heights_mm : heights of the shop's declared risers (its parallels' tops above their base, mm):
        a part over a riser of unknown height is tested against them (``locate._declared_riser``)
    table_tilt_sigmas : 0, or how many of the table's own sigmas (its height and tilt at the part,
        :func:`.uncertainty.table_plane_sigma`) the part's stance may take besides its contact's:
        each flat fine fit is then fitted once more in 6 DoF before it is scored, and the contact
        prior is as loose. For a fixture read through a table seen by few markers, whose tilt then
        levels the table (:mod:`app.vision.table_levelling`)
    final_reweight : Cauchy re-solves of the final 6-DoF fit per round (``refine_pose``'s
        ``reweight``); 0 keeps its soft-L1 solve alone
    """

    gamma: float = 2.2
    height_offsets_mm: tuple = (0.0,)
    free_height: bool = False
    resting_states: tuple | None = None
    min_score: float = 0.5
    min_verified_score: float = 0.0
    min_margin: float = 0.1
    min_distinctiveness: float = 0.1
    max_unexplained: float = 0.7
    lines_across: bool = True
    max_tilt_deg: float = 0.5
    max_sigma_mm: float = 0.2
    max_sigma_deg: float = 0.1
    n_starts: int = 6
    n_planar: int = 10
    n_refine: int = 3
    settle_starts: bool = False
    n_coarse: int = 40
    coarse_step_max_mm: float = COARSE_STEP_MAX_MM
    turn_maxima: int = 0
    self_occlusion: bool = False
    max_edges: int = 60000
    search_threads: int = SEARCH_THREADS
    sigma_scale: float = SIGMA_SCALE
    stated_sigma_scale: float = STATED_SIGMA_SCALE
    seed: int = 0
    contact_sigma_mm: float = CONTACT_SIGMA_MM
    contact_sigma_deg: float = CONTACT_SIGMA_DEG
    free_contact_sigma_deg: float = FREE_CONTACT_SIGMA_DEG
    held_contact_sigma_deg: float = HELD_CONTACT_SIGMA_DEG
    riser_sigma_mm: float = RISER_SIGMA_MM
    final_reweight: int = 3
    riser_heights_mm: tuple = ()
    table_tilt_sigmas: float = 0.0

    def with_(self, **changes) -> LocateOptions:
        """A copy with ``changes``; an unknown name is a ``TypeError`` that names the known ones."""
        unknown = sorted(set(changes) - OPTION_NAMES)
        if unknown:
            raise TypeError(f"unknown locate option(s) {', '.join(unknown)}; known: {', '.join(sorted(OPTION_NAMES))}")
        for key in ("height_offsets_mm", "riser_heights_mm"):
            if key in changes:
                changes[key] = tuple(changes[key])
        if changes.get("resting_states") is not None:
            changes["resting_states"] = tuple(changes["resting_states"])
        return replace(self, **changes)


OPTION_NAMES = frozenset(f.name for f in fields(LocateOptions))
