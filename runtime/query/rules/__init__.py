"""The rule parser by job: the lexicon, tokens, the intent from cue words, each question kind's reader."""
