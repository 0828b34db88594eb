"""Composed sentence shapes for the reader's generator: per kind, a small grammar of interchangeable parts (who
stands where, what they face, what is asked, the choices listed, units, asides that name no object) whose
combinations give thousands of shapes, so that the reader learns each role from what surrounds it rather than
from a fixed sentence.

Grammar: `<a|b|c>` picks one alternative, `[x]` keeps x half of the time, `%NAME%` expands the fragment NAME;
`{obj}`, `{stand}`, `{face}`, `{ref}`, `{cands}`, `{unit}`, `{room}`, `{num}`, `{start}`, `{goal}`, `{way}`,
`{turn}`, `{loc}` are slots the generator fills (tagged), `{face@}` / `{ref@}` / `{obj@}` repeat the name drawn for
that slot. Written for this generator without reading the held-out wording sets (only which abilities failed).
"""
from __future__ import annotations

import re

import numpy as np

FRAGMENTS: dict[str, str] = {
    # where I stand
    "ME": "<i'm|i am|i'm standing|i am standing|i stand|i'm stood|i'm positioned|i'm sitting|i'm placed|"
          "i'm located|i've stopped|i stopped|i end up|i'm waiting|i find myself|i'm right|i'm just|i'm currently>",
    "AT": "<by|at|next to|beside|near|close to|right by|over by|right next to|alongside|against|just by|over at|"
          "in front of|at the side of|by the side of|up by|near to|nearby>",
    "IF": "<if|when|while|suppose|say|imagine|assuming|let's say|pretend|so|ok so|picture this:|hypothetically,>",
    "STAND": "<%IF% %ME% %AT% the {stand}|standing %AT% the {stand}|%ME% %AT% the {stand}|from the {stand}|"
             "at the {stand}|<my position is|my spot is|my location is> <at|by|next to> the {stand}|"
             "<put|place|imagine|picture> <me|yourself> <at|by|next to|beside> the {stand}|"
             "with me <at|by|next to|beside> the {stand}|%IF% i <stand|wait|stop|sit|am> %AT% the {stand}>",
    # what I face
    "LOOK": "<facing|looking at|looking towards|looking toward|facing towards|facing toward|looking in the direction "
            "of|turned toward|turned to face|gazing at|staring at|pointed at|pointing at|oriented toward|"
            "oriented towards|aimed at|looking over at|looking straight at|watching|peering at|with my face to|"
            "with my eyes on|eyes on|head turned to|looking across at|turned towards|looking ahead at|"
            "facing straight at|looking directly at>",
    "AHEAD": "<in front of me|straight ahead|ahead of me|dead ahead|right in front of me|before me|directly ahead|"
             "straight in front of me|directly in front of me|in front|ahead>",
    "FACE": "<%LOOK% the {face}|<and|,|while|with> [i'm|i am] %LOOK% the {face}|with the {face} %AHEAD%|"
            "<and|,> [i] <have|got|see|can see> the {face} %AHEAD%|<and|,> the {face} is %AHEAD%|"
            "<and|,> [i] <face|look at|look towards|turn to|turn towards|look toward|stare at|look straight at> "
            "the {face}|<my face|my nose|my body|my gaze|my front> <pointing|turned|pointed|directed> "
            "<at|to|toward|towards> the {face}|so that the {face} is %AHEAD%>",
    "FACESENT": "<i'm %LOOK% the {face}|the {face} is %AHEAD%|i <face|look at|look towards> the {face}|"
                "i <have|see> the {face} %AHEAD%|my eyes are on the {face}|in front of me is the {face}>",
    # the choices
    "CHE": "<left or right|on the left or on the right|to the left or to the right|left side or right side|"
           "on my left or my right|to my left or my right|left or right of me|on the left-hand or right-hand side|"
           "left or right side|on my left or on my right|left-hand or right-hand>",
    "CHM": "<left, right or behind|left, right, or back|to my left, to my right, or behind me|left or right or "
           "behind me|left/right/back|on my left, my right or behind|left, right or at my back|"
           "left, right, or somewhere behind me|to the left, right or back>",
    "CHH": "<front-left, front-right, back-left or back-right|front left, front right, back left, or back right|"
           "front-left/front-right/back-left/back-right|in the front-left, front-right, back-left or back-right|"
           "ahead-left, ahead-right, behind-left or behind-right>",
    "CH": "<%CHE%|%CHE%|%CHM%|%CHH%>",
    "QUAD": "<which quadrant|what quadrant|which of the four quadrants|which corner|which diagonal>",
    "QOBJ": "<is the {obj} %CH%|<where is|where's|where would be|where would i find|where do i find|where will i "
            "see|where should i look for|where would i see> the {obj}[ relative to me| from there| from my "
            "position| from that spot| from where i am]|which side is the {obj} on|<on|to> which side <is|would "
            "be|will be|lies> the {obj}|the {obj} <—|-|:|,> is it %CH%|%QUAD% <is|would> the {obj} <in|be in|"
            "fall in|lie in>|does the {obj} <appear|seem|show up|lie|sit|end up|come out> %CH%|in which direction "
            "<is|would be|lies> the {obj}|which way is the {obj}|<tell me|say> whether the {obj} is %CH%|would "
            "the {obj} be %CH%|is the {obj} <%CHE%|%CHM%> of the {face@}|relative to the {face@}, is the {obj} "
            "%CHE%|what side of me is the {obj} on|the {obj} <would be|is> <where|on which side|in which "
            "quadrant>|<can you tell|could you say|do you know> <where|which side|which way> the {obj} is|"
            "<is|would> the {obj} <be> %CH% from where i am|in %QUAD% is the {obj}|the {obj} is <on my|to my> "
            "<left or right|left or my right>>",
    # distances
    "DQ": "<how far <is|'s|sits|lies|stands> the {obj} from the {obj}|how far apart are the {obj} and the {obj}|"
          "<what is|what's|tell me|give me|estimate|i need> the <distance|gap|space|spacing|separation> between "
          "the {obj} and the {obj}|the {obj} <—|-|:|,> how far <is it|away is it|is that> from the {obj}|"
          "how <many|much> {unit} <are there|is it|lie|sit> between the {obj} and the {obj}|<distance|how far> "
          "from the {obj} to the {obj}|how close <is|are> the {obj} <to|and> the {obj}|the {obj} and the {obj} "
          "<—|:|,> how far apart [are they]|how much <space|room|distance|floor> is there between the {obj} and "
          "the {obj}|if i walk from the {obj} to the {obj}, how far is it|how near <is|are> the {obj} <to|and> "
          "the {obj}|<measure|estimate|work out> the distance from the {obj} to the {obj}|from the {obj} to the "
          "{obj}, <how far|what distance|how many {unit}>|how far <away|off> is the {obj} <from|relative to> "
          "the {obj}|<what|how> <distance|far> <separates|lies between> the {obj} and the {obj}|between the "
          "{obj} and the {obj}, <how far|what's the gap|what distance>>",
    "DX": "<edge to edge|from edge to edge|closest points|at their closest points|nearest points|between the "
          "nearest edges|between them|from each other|apart|in a straight line|as the crow flies|the gap only|"
          "closest edge to closest edge|measuring between their closest parts|not centre to centre|the shortest "
          "gap|nearest edge to nearest edge|at the nearest point|from one to the other|side to side|"
          "surface to surface>",
    "UNITC": "<in|in|answer in|give it in|using|measured in|expressed in|units:|in terms of|answer using> {unit}",
    # sizes
    "LONGEST": "<at its longest|at its biggest|at its largest|along its longest side|end to end|from end to end|"
               "from one end to the other|along the longest edge|lengthwise|on its longest side|at the longest "
               "point|in its biggest dimension|across its longest side>",
    "DIMW": "<dimension|side|edge|measurement|extent|length|axis|span>",
    "SQ": "<how <big|long|large> is the {obj}[ %LONGEST%]|what <is|'s> the <longest|biggest|largest|greatest|"
          "maximum|max|longest single> %DIMW% of the {obj}|what <length|size> <does the {obj} come to|is the "
          "{obj}> %LONGEST%|the {obj} <—|:|,> how <long|big> is it[ %LONGEST%]|how many {unit} <long|across|big|"
          "end to end> is the {obj}|<measure|estimate|gauge|size up> the {obj}'s <longest side|biggest dimension|"
          "length|size|longest edge>|<length|height|width>, <width|depth> or <height|depth> of the {obj}, "
          "whichever is <biggest|largest|longest>|what would the {obj} measure %LONGEST%|<tell me|give me|i need> "
          "the {obj}'s <size|dimensions|longest dimension|length>|the <longest|biggest> <side|edge|dimension> of "
          "the {obj}, <how long is it|what is it>|how <long|big|large> would you say the {obj} is|what's the "
          "{obj}'s <length|size> %LONGEST%|how long <does|would> the {obj} <measure|run|stretch|go>[ %LONGEST%]|"
          "how tall is the {obj}|how wide is the {obj}|what is the height of the {obj}>",
    "GUESS": "<is it <more|less|bigger|smaller|longer|shorter> than {num} {unit}|i <guess|think|reckon> <about|"
             "around|roughly> {num} {unit}|maybe {num} {unit}|<over|under|about> {num} {unit}?>",
    # counts
    "CQ": "<how many {obj} <are there|are in here|can you see|do you see|did you see|can be seen|are visible|are "
          "present|have you spotted|did you count|are in the {room}|does the {room} have|exist|show up|are around|"
          "were there|in total|altogether|i have|we have|are in this {room}|in the {room}|can i find|can you find|"
          "could you count|are in the whole {room}|are in view|appear|did the video show|are in the place>|"
          "<count|tally|number> the {obj}[ in the {room}| for me| please]|<could you|can you|would you|please> "
          "<do a count of|count|tally up|total up|tell me the number of|give me the number of|give me a count "
          "of|count up|work out the number of> the {obj}[ in the {room}| in this {room}| for me]|<what is|what's|"
          "tell me> the <number|count|total number|total count|quantity|amount|total|tally> of {obj}[ in the "
          "{room}| here| in view| in the video]|{obj} <—|:|,> how many[ are there| in total| do you see]|"
          "<in|across|throughout> <the|this|the whole|this whole> {room}, how many {obj} <are there|do you "
          "see|can you spot|exist>|are there <many|any|lots of|a lot of|several> {obj}? how many|how many "
          "<individual|separate|distinct|different> {obj} <are there|can you spot|do you see>|what number of "
          "{obj} <are|is> <there|in the {room}>|<i'd like|i want|i need> <to know|a count of> how many {obj} "
          "<there are|are in the {room}>|<count up|total|add up> all the {obj} <you see|in the {room}|you saw>|"
          "number of {obj} <in the {room}|present|visible|you can see>, please>",
    "ALLROOMS": "<all rooms together|every room combined|summing all the rooms|counting every room|across the "
                "whole place|the whole thing together|all the rooms added up|every space combined|including every "
                "room|all areas included|the entire place|everything combined>",
    "RQ": "<<how big|how large|how spacious|what size> is <the|this> {room}[ in {unit}]|<what is|what's|estimate|"
          "tell me|give me|calculate|work out> the <floor area|area|floor space|square footage|size|total area|"
          "total floor area|surface area|footprint|floor size> of <the|this> {room}[ in {unit}]|how many {unit} "
          "<is|does> <the|this> {room}[ cover| have| take up| measure]|<the|this> {room}'s <area|floor area|size|"
          "square footage>[ in {unit}]|how much <floor|floor space|space|area> <is there|does the {room} have|does "
          "the {room} cover>|<could you|can you> <estimate|work out|figure out|tell me> <the floor area|how big "
          "the {room} is|the area of the {room}|the square footage>[ in {unit}]|<what|how much> area does <the|"
          "this> {room} <cover|take up|have>>",
    # nearest / farthest
    "N": "<two|three|four|five|2|3|4>",
    "WHICH": "<which|which one|which object|which item|which thing|which of these|which of them|which of the "
             "following|which one of these %N%|which of these %N%|which of the %N%|what>",
    "CL": "<closest|nearest|nearer|the closest|the nearest|least far|the least far|most near|closer>",
    "FA": "<farthest|furthest|most distant|farthest away|furthest away|the farthest|the furthest|further|"
          "farther|most far|the most distant|furthest off>",
    "LIST": "<: {cands}|, {cands}| — {cands}|? {cands}| - {cands}|: is it {cands}|; options: {cands}>",
}

SHAPES2: dict[str, list[str]] = {
    "direction": [
        "%STAND%, %FACE%, %QOBJ%", "%STAND% %FACE%. %QOBJ%", "%STAND% %FACE% — %QOBJ%", "%STAND% %FACE%; %QOBJ%",
        "%ME% %AT% the {stand}. %FACESENT%. %QOBJ%", "%STAND%, %FACE%: %QOBJ%",
        "%LOOK% the {face} <from|while at|while standing by|at|by> the {stand}, %QOBJ%",
        "%QOBJ% <if|when> %ME% %AT% the {stand} %FACE%", "%QOBJ%, %STAND% %FACE%",
        "the {obj}: %STAND% %FACE%, <which side is it on|is it %CH%|where is it|%QUAD% is it in>",
        "<a person|someone|my friend|a robot|the camera|somebody> <standing|stood|positioned|waiting> %AT% the "
        "{stand} <and|,> <facing|looking at|looking towards> the {face} <—|:|,> <is|would> the {obj} <be> <on "
        "their|to their> <left or right|left, right or behind them|front-left, front-right, back-left or "
        "back-right>",
        "%FACESENT% <and|,> %ME% %AT% the {stand}. %QOBJ%", "<at|from|by> the {stand}, %LOOK% the {face}: %QOBJ%",
        "%STAND% %FACE%, <tell me|i want to know|can you say> <where the {obj} is|which side the {obj} is on|if "
        "the {obj} is %CH%>",
    ],
    "distance": ["%DQ%", "%DQ%, %DX%", "%DQ% %UNITC%", "%DQ%, %DX%, %UNITC%", "%DQ% (%DX%) %UNITC%",
                 "%DQ%? %DX%, %UNITC%", "%DQ% — %UNITC%", "%UNITC%, %DQ%", "%DQ%? %UNITC% please",
                 "%DQ% %DX%"],
    "size": ["%SQ%", "%SQ% %UNITC%", "%SQ%? %UNITC%", "%UNITC%, %SQ%", "%SQ%, %GUESS%", "%SQ% %UNITC%. %GUESS%",
             "%SQ% — %UNITC%", "%SQ% (%UNITC%)"],
    "count": ["%CQ%", "%CQ%", "%CQ%, %ALLROOMS%", "%CQ% (%ALLROOMS%)"],
    "room_size": ["%RQ%", "%RQ%, %ALLROOMS%", "%RQ%? %ALLROOMS%", "%RQ% %UNITC%", "%RQ% — %ALLROOMS%, %UNITC%",
                  "%UNITC%, %RQ%", "%RQ%. if there are several rooms, <add them up|combine them|take them all>"],
    "closest": [
        "%WHICH% is %CL% to the {ref}[%LIST%]", "<of|among|out of|from> [the|these] {cands}, which [one] is %CL% "
        "[to] the {ref}", "<from|measured from|starting from|relative to|looking from> the {ref}, which is "
        "%CL%[%LIST%]", "%CL% to the {ref}%LIST%", "which of {cands} <sits|is|lies|stands|is located> %CL% to "
        "the {ref}", "the {ref}: which <of {cands}|one> is %CL% to it", "<pick|choose|name|select|tell me> the "
        "one %CL% to the {ref}[%LIST%]", "i have {cands}; which is %CL% to the {ref}",
        "%WHICH% is %CL% to the {ref}[%LIST%], measuring from the {ref@}", "what is %CL% the {ref}[%LIST%]",
        "%WHICH% <is|lies|sits> %CL% the {ref}[%LIST%]",
    ],
    "farthest": [
        "%WHICH% is %FA% from the {ref}[%LIST%]", "<of|among|out of|from> [the|these] {cands}, which [one] is %FA% "
        "from the {ref}", "<from|measured from|starting from|relative to|looking from> the {ref}, which is "
        "%FA%[%LIST%]", "%FA% from the {ref}%LIST%", "which of {cands} <sits|is|lies|stands|is located> %FA% "
        "from the {ref}", "the {ref}: which <of {cands}|one> is %FA% from it", "<pick|choose|name|select|tell "
        "me> the one %FA% from the {ref}[%LIST%]", "i have {cands}; which is %FA% from the {ref}",
        "%WHICH% is %FA% <away from|from> the {ref}[%LIST%], measuring from the {ref@}",
    ],
    "appearance": [
        "<in what order|in which order|what order> <do|did> {cands} <first appear|show up first|first come into "
        "view|appear for the first time>[ in the <video|clip|footage|recording>]",
        "<order|sort|rank|arrange|list> {cands} by <when they first appear|first appearance|the time they are first "
        "seen|when you first see them>", "which <came|comes|appears|showed up> first[ in the video]%LIST%",
        "{cands}: <what order did they appear in|which was seen first|in what sequence do they first show up>",
    ],
    "route": [
        "<starting|i start|i'm> <at|by|from> the {start} <facing|looking at|with> the {face}[ ahead], <i want to|how "
        "do i|i need to> <get|go|walk> to the {goal}. <1.|first,|step 1:> <go|walk|head> <forward|straight|ahead> "
        "<until|to|till> the {way} <2.|then,|step 2:> {turn} <3.|then,|step 3:> <go|walk|head> <forward|straight> "
        "<until|to|till> the {goal@}",
    ],
    "other": [
        "what <colour|color|material|brand|style> is the {obj}", "<who|when|why> <put|bought|moved> the {obj}[ "
        "there]", "does the {obj} <work|look new|need cleaning>", "should i <move|sell|clean|replace> the {obj}",
        "<can you|could you> describe the {obj}", "what's <inside|on top of|under> the {obj}",
        "is the {obj} <nicer|older|more expensive|cheaper> than the {obj}", "<what|which> <song|film|show> is on",
        "is the {obj} <switched on|open|broken|plugged in>", "what is the {obj} made of",
        "<summarise|describe> the <video|room|clip>", "what happened in the <video|clip>",
    ],
}
_GROUP = re.compile(r"<([^<>\[\]]*)>|\[([^<>\[\]]*)\]")
_MACRO = re.compile(r"%([A-Z]+)%")


def expand(template: str, rng: np.random.Generator) -> str:
    """One sentence shape from a grammar template (macros, then innermost groups first)."""
    t = template
    for _ in range(8):
        t2 = _MACRO.sub(lambda m: FRAGMENTS[m.group(1)], t)
        if t2 == t:
            break
        t = t2
    while True:
        m = _GROUP.search(t)
        if m is None:
            break
        alts = (m.group(1) if m.group(1) is not None else m.group(2)).split("|")
        rep = alts[int(rng.integers(len(alts)))] if m.group(1) is not None or rng.random() < 0.5 else ""
        t = t[:m.start()] + rep + t[m.end():]
    return re.sub(r"\s+", " ", t).strip()
