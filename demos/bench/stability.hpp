// The stability suite: hard cases run on sinew and on Bullet's two couplings (being written).
#pragma once
