"""gymnasium environments for step-size control over the compiled loop. Importing this
package registers `"nivpjax/StepSize-v0"` (and `gymnasium.make_vec` uses
[`nivpjax.rl.StepSizeVectorEnv`][] through `vector_entry_point`).

The core (`nivpjax._*`) never imports this package."""

import gymnasium

from ._gym import StepSizeGymEnv as StepSizeGymEnv, StepSizeVectorEnv as StepSizeVectorEnv


ENV_ID = "nivpjax/StepSize-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=ENV_ID,
        entry_point="nivpjax.rl._gym:StepSizeGymEnv",
        vector_entry_point="nivpjax.rl._gym:StepSizeVectorEnv",
    )
