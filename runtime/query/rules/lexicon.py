"""Word lists of the rule parser: function words, units, scene words, selectors, directions, example wordings."""
from __future__ import annotations

import re

from ..ir import COMPARATIVES, SUPERLATIVES, UNIT_M  # noqa: F401 (UNIT_M: the parser's units)

UNIT_WORDS = {"m": "m", "meter": "m", "meters": "m", "metre": "m", "metres": "m", "cm": "cm", "centimeter": "cm",
               "centimeters": "cm", "centimetre": "cm", "centimetres": "cm", "mm": "mm", "millimeter": "mm",
               "millimeters": "mm", "millimetre": "mm", "millimetres": "mm", "ft": "ft", "foot": "ft", "feet": "ft",
               "inch": "in", "inches": "in"}
DET = {"the", "a", "an", "my", "this", "that", "these", "those", "your", "our", "any", "some", "each", "every",
        "all", "its", "his", "her", "their", "another", "other"}
STOP = set("""
i me you we us he she it they one ones i'm im you're we're it's what's where's that's there's here's who's how's
is are am was were be been being do does did don't doesn't have has had will would should could can may might must
if when while as so and or nor but then than also too either neither both whether not no yes
what which who whom whose where how why there here
of in on at by to from with without into onto toward towards near nearby beside besides next between among amongst
around about across along behind under over above below beneath inside outside within against up down through via
left right front back rear ahead forward forwards backward backwards side sides front-left front-right back-left
back-right left-hand right-hand front-right-hand straight directly direction directions located positioned
situated placed sits sit sitting stand standing stood stands face facing faced faces look looking looked looks
turn turned turning walk walking go going see seen saw spot notice find found show tell give list name named
closest nearest farthest furthest closer nearer farther further close far apart away distance distances gap
many much more most less least number count total quantity amount fewer fewest common numerous plentiful greater
big bigger biggest large larger largest small smaller smallest tall taller tallest short shorter shortest long
longer longest wide wider widest narrow narrower narrowest high higher highest low lower lowest deep size sizes dimension dimensions length
width height depth measure measures measured measuring measurement measurements area footprint square
volume elevation hung installed fixed relative relation respect regard half counting excluding including
leave leaving forgot forget forgotten drop dropped lost present visible separating spacing separation
option options choice choices following eyes gaze oriented orientated position location pointing gazing
watching staring
point points object objects thing things item items stuff furniture piece pieces kind kinds type types
please thanks roughly approximately approx around exactly just only really actually about estimate guess
first second third fourth fifth last order appear appears appeared appearance came come comes seen
showed shown shows popped appearing
earliest latest earlier later sooner soonest sequence until till robot start starts starting begin begins beginning
cm centimeter centimeters centimetre centimetres mm millimeter millimeters millimetre millimetres m meter meters
metre metres ft foot feet inch inches sq
for about like per upon unto via else off out over onto into than
wonder wondering wondered suppose supposing imagine say know want wanted need think tell give let guess curious
question quick hey hi hello ok okay so um please r u ur pls plz separate separates separated sits lies lie
edge edges extent way ways spot part parts portion
exist exists existing fall falls belong belongs hang hangs hanging rest rests resting lying kept mounted put
placed shown fit fits go goes come comes get gets got keep keeps contain contains include includes hold holds
lie lies occupy occupies measure
maximum max minimum min overall total approximate rough
everything anything something nothing everyone all anywhere somewhere everywhere
whichever whatever whoever whenever wherever altogether anyway anyhow though although also again already still
even ever quite rather very perhaps maybe yet instead otherwise together
me myself mine origin axis y-axis x-axis cartesian plane quadrant quadrants degrees degree
""".split())
COPULA = {"is", "are", "was", "were", "be", "been", "being", "get", "got", "gets"}
# content words that are also function words: "tv stand", "trash can", "side table", "front door"
SOFT_AFTER_NOUN = {"stand", "can", "light", "lights", "top", "set", "table"}
SOFT_BEFORE_NOUN = {"side", "end", "top", "back", "front", "corner", "coffee", "night", "standing", "sitting",
                     "long", "high", "low", "light", "square", "first", "second"}
SCENE = {"room", "rooms", "kitchen", "bedroom", "bathroom", "living", "dining", "space", "scene", "video", "house",
          "apartment", "flat", "office", "place", "area", "home", "floor", "hall", "hallway", "corridor", "here",
          "interior", "map", "image", "picture", "ground"}
# a part of the room as a location ("in the middle of the room", "in the corner"): no object of that name
ROOM_REGION_RX = (r"\b(?:in|at|into|near|by|from|to|toward|towards) the (?:middle|center|centre|corner|corners)"
                   r"(?: of (?:the |this |my )?(?:" + "|".join(sorted(SCENE)) + r"))?"
                   r"(?=$| ?[?,.;:!]| (?:of|and|or|is|are|was|were|facing|looking)\b)")  # not "the corner table"
COLOURS = {"red", "blue", "green", "yellow", "black", "white", "grey", "gray", "brown", "orange", "pink", "purple",
            "beige", "silver", "gold", "golden", "dark", "light-coloured", "wooden", "wood", "metal", "metallic",
            "leather", "plastic", "glass", "fabric", "striped", "old", "new", "modern", "broken", "open", "closed"}
ORDINALS = {"first", "second", "third", "fourth", "fifth", "last", "other", "left", "right", "middle", "1st",
             "2nd", "3rd"}
RANKS = {"second", "third", "fourth", "fifth", "2nd", "3rd", "4th", "5th", "penultimate"}
CMP = "(?:" + "|".join(COMPARATIVES) + ")"
CMP_RX = rf"\b{CMP}\b"
SUP_RX = r"\b(?:" + "|".join(SUPERLATIVES) + r")\b"
# "the longest side of the bed", "the biggest dimension of the tv": a size question, not a comparison
SUP_DIM_RX = SUP_RX + r"(?: of (?:its|their|the|his|her))? (?:sides?|dimensions?|edges?|extents?|length|measurements?|axis|axes)\b"
NEAR_CUES = {"nearest", "closest", "next", "beside", "near", "by", "nearer", "closer"}
DIR_PHRASES = [  # (regex over the joined tokens, canonical direction)
    (r"front-left|front left|left front|forward left|ahead (?:and )?(?:to the )?left", "front-left"),
    (r"front-right|front right|right front|forward right|ahead (?:and )?(?:to the )?right", "front-right"),
    (r"back-left|back left|rear left|left rear|behind (?:and )?(?:to the )?left|left behind", "back-left"),
    (r"back-right|back right|rear right|right rear|behind (?:and )?(?:to the )?right|right behind", "back-right"),
    (r"\bleft\b", "left"), (r"\bright\b", "right"), (r"\bbehind\b|\bback\b|\brear\b", "back"),
    (r"\bin front\b|\bahead\b|\bfront\b", "front")]
DIR_RX = [(re.compile(rx), lab) for rx, lab in DIR_PHRASES]
QUADRANTS = ("front-left", "front-right", "back-left", "back-right")

EXAMPLES: dict[str, list[str]] = {
    "object_counting": ["How many chairs are there?", "Count the cushions in the room.",
                        "How many cups are on the table?", "How many chairs are near the desk?"],
    "object_existence": ["Is there a fridge in this kitchen?", "Do you see any trash cans?",
                         "Is there a laptop on the desk?", "Is the cup on the table?", "Are there two chairs?",
                         "Is there anything between the sofa and the tv?"],
    "object_size_estimation": ["How big is the sofa?", "How tall is the lamp in inches?",
                               "What is the longest side of the bed, in cm?",
                               "How high above the floor is the tv?"],
    "object_abs_distance": ["How far is the table from the tv?", "What's the distance between the sofa and the "
                            "stove in feet?", "How far am I from the tv?", "Is the sofa within 2 m of the tv?"],
    "object_rel_distance": ["Which is closest to the tv: the chair, the stool or the sofa?",
                            "Is the bed or the sofa farther from the door?"],
    "object_nearest": ["What is the nearest object to the fridge?", "What's farthest from the bed?"],
    "object_count_compare": ["Are there more chairs than tables?", "Which are there fewer of, cups or bottles?"],
    "object_size_compare": ["Which is bigger, the table or the sofa?", "Is the fridge taller than the door?",
                            "What's the biggest object in the room?",
                            "How much taller is the fridge than the table?"],
    "object_rel_direction": ["Standing by the sofa facing the tv, is the lamp to my left?",
                             "If I stand at the stove and look at the fridge, is the table front-left, front-right, "
                             "back-left or back-right of me?"],
    "object_where": ["Where is the printer?", "Where's the trash can?", "Which way to the door?"],
    "object_view_direction": ["Is the lamp to the left of the sofa?", "Is the cup behind the tv?"],
    "object_list": ["What objects are in the room?", "List the chairs.", "What's on the table?", "What is to my left?",
                    "What's under the desk?"],
    "room_size_estimation": ["How big is this room?", "What is the floor area of the room in square meters?"],
    "obj_appearance_order": ["Which did I see first, the tv or the sofa?"],
}




# ----------------------------------------------------------------------------- locations, stances, numbers

LOCATION = {"on", "in", "at", "near", "by", "under", "behind", "beside", "above", "below", "inside", "against",
             "around", "next", "between", "over", "beneath", "underneath", "along", "across", "close"}


# "A is left of / in front of / behind B" without a stance: as the viewer (the last camera) sees them
VIEW_RX = r"\b(?:(?:to|on|at) the (?:left|right)(?: hand side| side)? of|left of|right of|in front of|behind)\b"
VIEW_WORDS = {"left": "left", "right": "right", "front": "front", "behind": "back"}
# location words the map reasoner can apply to a count or an is-there question (`answer.relation_holds`)
RELATION_WORDS = {"on": "on", "atop": "on", "onto": "on", "upon": "on", "near": "near", "by": "near",
                   "beside": "near", "around": "near", "in": "in", "inside": "in", "within": "in",
                   "under": "under", "below": "under", "beneath": "under", "underneath": "under",
                   "above": "above", "over": "above", "between": "between"}
TESTED = "on, near, in, under and above one object, or between two"  # the relations, in words
# any location word, as a regex alternation for the intents: tested by the map, or refused naming it
LOCATED = "(?:" + "|".join(sorted(LOCATION | set(RELATION_WORDS))) + ")"
WHAT_AT_RX = (rf"^(?:what|what's|which (?:objects|things|items))(?: is| are| was| were|'s)? (?:there )?(?:sitting |"
               rf"lying |standing |placed |kept |stored |located |hanging |resting )?{LOCATED}\b")


# a pronoun after a location ("the chairs next to it") stands for an object named earlier: resolved or refused
PRONOUNS = {"it", "them", "that", "this", "those", "these"}
# the words a located pronoun may follow: every location word the parser tests or refuses, and the selectors'
# closeness words ("nearest (to) it"); left / right / front of a stance question are `_stance`'s
PRONOUN_CUES = LOCATION | set(RELATION_WORDS) | NEAR_CUES | {"top"}

FACE1 = {"facing", "face", "faces", "faced", "towards", "toward", "watching"}
PLACED_VERBS = {"am", "i'm", "im", "standing", "stand", "sitting", "sit", "be", "was", "were", "stood", "sat"}
# "standing by the bed with the sofa in front of me": facing the sofa
AHEAD_OF_ME = r"(?:(?:right|straight|directly|just|dead) )?(?:in front of|ahead of|before) (?:me|us|you|it|him|her|them)\b"  # "with the sofa in front of me"
IS_AHEAD = r"(?:is|are) (?:straight |directly |right )?(?:ahead|in front of me)\b"  # "the tv is straight ahead"
FACING_AHEAD_RX = (rf"\b(?:with|have|having|got) (?:the |a |an )?[^,?]{{1,40}}? {AHEAD_OF_ME}|\b{IS_AHEAD}|(?:^|[,:;.] )(?:the |a |an )"
                   rf"[^,?.]{{1,40}}? {AHEAD_OF_ME}")
FACE2 = {"looking at", "look at", "looked at", "staring at", "turned to", "turn to", "direction of", "looking toward",
          "gazing at", "gaze at", "face to", "faced to", "facing to", "faces to",
          "look toward", "looking towards", "look towards", "eyes on", "gaze on", "looking over", "pointed at",
          "pointing at", "oriented toward", "oriented towards"}


NUMBERS = {w: i for i, w in enumerate("zero one two three four five six seven eight nine ten eleven twelve".split())}
COUNT_OPS = {"more than": ">", "over": ">", "at least": ">=", "fewer than": "<", "less than": "<", "under": "<",
              "at most": "<=", "exactly": "==", "only": "==", "just": "=="}
COUNT_RX = re.compile(r"^(?:is|are) there (?:(" + "|".join(COUNT_OPS) + r") )?(\d+|" + "|".join(NUMBERS) + r")\b")

# "is the sofa within 2 m of the tv?", "is the bin more than half a metre from the desk?": a distance against a length
DIST_OPS = {"within": "<=", "less than": "<", "closer than": "<", "nearer than": "<", "under": "<", "at most": "<=",
             "no more than": "<=", "more than": ">", "further than": ">", "farther than": ">", "over": ">",
             "at least": ">=", "no less than": ">="}
DIST_CMP_RX = (r"\b(" + "|".join(sorted(DIST_OPS, key=len, reverse=True)) + r") (?:about |around |roughly )?"
                r"(\d+(?:\.\d+)?|half an?|an?|one|two|three|four|five|six|seven|eight|nine|ten) ?" + r"(cm|centimet\w+|mm|"
                r"millimet\w+|m|meters?|metres?|feet|foot|ft|inch(?:es)?)\b (?:away )?(?:of|from|to)\b")

CLOSE = r"\b(?:closest|nearest|closer|nearer)\b"
FAR = r"\b(?:farthest|furthest|farther|further)\b"
# a choice is asked (else a closeness word selects): "which ...", "... or ...", "name / pick the object closest to"
WHICH = (r"\b(?:which|whichever|what|what's|or|than)\b|^(?:name|pick|identify|choose|select)\b|"
          r"\b(?:name|pick|identify|choose|select) the (?:object|thing|item|one)\b")

def examples() -> list[str]:
    """Example wordings the map reasoner understands (also listed by `mosaic ask --examples`)."""
    return [e for es in EXAMPLES.values() for e in es]
