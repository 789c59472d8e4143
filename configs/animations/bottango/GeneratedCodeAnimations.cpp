// GENERATED CODE (a hilsim sample in Bottango's export layout)
// Animation Index Key:
// 0: Talk
// 1: Idle
#include "GeneratedCodeAnimations.h"
namespace GeneratedCodeAnimations
{
	// setup
	const char SETUP_DATA_0[] PROGMEM = "rSVPin,0,1000,2000,3000,1500\nrSVI2C,64,3,2000,1"
		"000,3000,1500\nrECOnOff,lamp,0,12\n";
	const char* const SETUP_DATAARRAY[] PROGMEM = { SETUP_DATA_0 };

	// animation 0, "Talk"
	const char ANIM_0_DATA0[] PROGMEM = "sC,0,0,2000,4096,513,0,7110,-763,814\nsC,643,0,1"
		"500,0,400,0,8192,-400,0\nsC,0,";
	const char ANIM_0_DATA1[] PROGMEM = "2000,1000,7110,331,-354,2277,-331,931\nsC,643,25"
		"00,500,8192,100,0,4096,-100,0\n";
	const char* const ANIM_0_DATAARRAY[] PROGMEM = { ANIM_0_DATA0, ANIM_0_DATA1 };
	const char ANIM_0_LOOP[] PROGMEM = "";
	const uint16_t ANIM_0_CONFIG[] PROGMEM = { 0, 0, 0, 10, 0, 1, 0, 0 };

	// animation 1, "Idle"
	const char ANIM_1_DATA0[] PROGMEM = "sCI,0,4096\nsCO,lamp,0,1\nsC,0,500,3";
	const char ANIM_1_DATA1[] PROGMEM = "000,4096,1000,800,4096,-1000,800\n";
	const char* const ANIM_1_DATAARRAY[] PROGMEM = { ANIM_1_DATA0, ANIM_1_DATA1 };
	const char ANIM_1_LOOP[] PROGMEM = "sC,0,0,200,4096,50,0,4096,-50,0\n";
	const uint16_t ANIM_1_CONFIG[] PROGMEM = { 0, 0, 1, 0, 1, 0, 0, 0 };
	/* CommandStream* unused() { return nullptr; } */
}
