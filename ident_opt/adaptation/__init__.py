"""Online identification next to the controller: exact warm-started re-solves after every sample.

| module       | what it holds                                                                              |
|--------------|--------------------------------------------------------------------------------------------|
| `identifier` | `OnlineIdentifier`: statistics updated by rank-n steps, bounded least squares re-solved warm, |
|              | the GMR residual's consistency transform, the guard against poison samples                 |
| `kernel`     | the same update as compiled C (`pi_update`), attached to an identifier                      |
| `stream`     | the streaming service: samples in on standard input, one JSON line out per sample           |
| `replay`     | offline fit on the first part of a trial, then the rest replayed sample by sample; the batch check |
"""
