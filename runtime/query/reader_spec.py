"""What the trained reader predicts (shared by its training in export/reader and its runtime in query/reader).

KINDS: the question kinds of the classification head ("other": a question no program answers); ROLES: the token
roles of the tagging head, tagged BIO ("B-OBJ", "I-OBJ", ... and "O"). Changing either means retraining.
"""
KINDS = ("count", "size", "room_size", "distance", "closest", "farthest", "direction", "route", "appearance",
         "other")
# OBJ: the object asked about; STAND / FACE: where I stand / what I face; CAND: compared or listed objects; REF: the
# object distances are measured from; UNIT; NUM; START / GOAL / WAY / TURN: a route; LOC: a place a count is at
ROLES = ("OBJ", "STAND", "FACE", "CAND", "REF", "UNIT", "NUM", "START", "GOAL", "WAY", "TURN", "LOC")
TAGS = ("O",) + tuple(f"{p}-{r}" for r in ROLES for p in "BI")
MAX_TOKENS = 192  # word pieces read (a longer question is refused by the reader, said so)
SPEC_VERSION = "mosaicthinker.reader/1"
