"""The literature problems of the robustness set, by name, as a lazy table: listing them
(``olado list``) imports none of their modules; building one imports its module only.

``CATALOG`` maps a problem name to (module in :mod:`olado.problems`, one-line summary); the
module's ``PROBLEMS`` dictionary holds the factory under the same name. :func:`lazy_factories`
turns the table into the name -> factory entries that :data:`olado.problems.PROBLEMS` holds.
"""

from __future__ import annotations

import importlib
import inspect

__all__ = ["CATALOG", "LazyFactory", "lazy_factories"]

#: name -> (module, summary); order: variants of the built-ins, COPS, literature, aerospace (seeds 004/002), seed 000 (worhp), infeasible
CATALOG = {
    "rayleigh-mixed": ("variants", "Rayleigh problem with the mixed constraint u + x1/6 <= 0 (Maurer and Augustin 2001)."),
    "goddard": ("cops", "Goddard rocket, maximal altitude, free final time (COPS 3.0 'rocket')."),
    "hang-glider": ("cops", "Range of a hang glider in a thermal, free final time (COPS 3.0 'glider'; Betts 2010)."),
    "robot-arm": ("cops", "Minimum-time robot arm motion (COPS 3.0 'robot')."),
    "particle-steering": ("cops", "Minimum-time particle steering (COPS 3.0 'steering'; Bryson and Ho 1975)."),
    "catalyst-mixing": ("cops", "Catalyst mixing in a tubular reactor (COPS 3.0 'catmix')."),
    "hanging-chain": ("cops", "Hanging chain of given length (COPS 3.0 'chain')."),
    "brachistochrone": ("literature", "Brachistochrone to a vertical line, minimum time (Bryson and Ho 1975)."),
    "brachistochrone-point": ("literature", "Brachistochrone to a point, minimum time (Bryson and Ho 1975)."),
    "double-integrator": ("literature", "Minimum-energy double integrator (Bryson and Ho 1975 sec. 3.11)."),
    "bryson-denham": ("literature", "Minimum-energy double integrator with x <= 1/9 (Bryson-Denham problem)."),
    "bang-bang-cart": ("literature", "Minimum-time cart x'' = u, |u| <= 1 (Bryson and Ho 1975 sec. 7.3)."),
    "moon-lander": ("literature", "Minimum-fuel vertical soft landing, free final time (Meditch 1964)."),
    "lotka-fishing": ("literature", "Lotka-Volterra fishing problem, relaxed (Sager 2005)."),
    "batch-reactor": ("literature", "Consecutive reactions in a batch reactor (Ray 1981; Luus 2000)."),
    "alp-rider": ("literature", "Alp rider: stiff dynamics, a path constraint with four ridges (Betts 2010)."),
    "free-flying-robot": ("literature", "Free-flying robot, minimum fuel with path constraints (Sakawa 1999; Betts 2010)."),
    "dubins": ("literature", "Minimum-time Dubins car (Dubins 1957)."),
    "rigid-body": ("literature", "Minimum-time reorientation of an asymmetric rigid body (Betts 2010 sec. 6.8)."),
    "obstacle": ("literature", "Minimum-energy point mass around a circular obstacle (two local minima)."),
    "cart-pole": ("literature", "Cart-pole swing-up, minimum effort (Kelly 2017)."),
    "orbit-raising": ("literature", "Maximal-radius low-thrust orbit transfer (Bryson and Ho 1975 sec. 2.5)."),
    "shuttle-entry": ("aerospace", "Space Shuttle entry, maximum crossrange, free final time (Betts 2010 ex. 6.1; seed 004)."),
    "shuttle-entry-heating": ("aerospace", "Space Shuttle entry with the heat-rate limit q <= 70 BTU/ft^2/s (Betts 2010 ex. 6.1; seed 004)."),
    "low-thrust-geo": ("worhp", "Time-optimal low-thrust planar transfer to GEO (seed 000 sec. VI.1; Kluever 1995)."),
    "hypersonic-landing": ("worhp", "Emergency landing of a hypersonic upper stage, maximal range (seed 000 sec. VI.II)."),
    "lq-unreachable": ("infeasible", "lq-box with an unreachable terminal state (infeasible)."),
    "cart-too-short": ("infeasible", "Minimum-time cart in the fixed time 3 < 1 + sqrt 6 (infeasible)."),
    "chain-too-short": ("infeasible", "Hanging chain shorter than the distance of its end points (infeasible)."),
    "catalyst-overfull": ("infeasible", "Catalyst mixing with x1(1) + x2(1) >= 1.05 (infeasible)."),
    "steering-too-short": ("infeasible", "Particle steering in the fixed time 0.4 (infeasible)."),
    "vanderpol-contradict": ("infeasible", "Van der Pol with x1 >= 0.2 and x1 <= 0.1 at every stage (infeasible)."),
    "batch-overyield": ("infeasible", "Batch reactor with x2(1) >= 1.05 (infeasible)."),
}


class LazyFactory:
    """A problem factory whose module is imported on the first call (or when its signature is
    asked for: the command line checks settings against it). Its ``__doc__`` is the catalog's
    summary, so a listing reads it without importing anything."""

    def __init__(self, name: str, module: str, summary: str):
        self.problem_name = name
        self.module = f"{__package__}.{module}"
        self.__doc__ = summary

    def load(self):
        """The module's factory for this name (its module imported now)."""
        return importlib.import_module(self.module).PROBLEMS[self.problem_name]

    @property
    def __signature__(self):
        return inspect.signature(self.load())

    def __call__(self, *args, **kwargs):
        return self.load()(*args, **kwargs)

    def __repr__(self):
        return f"LazyFactory({self.problem_name!r}, {self.module!r})"


def lazy_factories() -> dict:
    """name -> :class:`LazyFactory` for every catalog entry."""
    return {name: LazyFactory(name, module, summary) for name, (module, summary) in CATALOG.items()}
