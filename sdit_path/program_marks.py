"""The comments that frame the test in our NC programs.

A program with an operator sequence (``post.operator_sequence``) first takes the
operator to the bar (the bar not mounted) and at the end back from it; the test's
motion lies between these two comments (any case, in the comment syntax of each
controller).  The posts write them; every reader of our programs (the LinuxCNC timing
model, the read-back of the chords, the oracles) takes the test from between them.
It lives below the stages because the timing model reads programs too."""

TEST_BEGINS = "the test begins here"
TEST_ENDS = "the test ends here"
